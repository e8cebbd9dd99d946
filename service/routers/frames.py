"""``/api/frames``: the live and frozen frames of the ring buffer, their images, freezing."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query
from fastapi.responses import Response

from ..frames import TooManyWaiters
from ..render import colorize_disparity, encode_jpeg, encode_png, frame_json
from ..schemas import MAX_ID
from ..state import State

router = APIRouter(prefix="/api/frames", tags=["frames"])
FrameId = Annotated[int, Path(ge=0, le=MAX_ID)]


@router.get("/latest")
async def latest(
    state: State, after: Annotated[int, Query(ge=0, le=MAX_ID)] = 0, wait: Annotated[float, Query(ge=0, le=10)] = 0.0
) -> dict[str, Any]:
    """The newest frame; with ``wait``, the first one newer than ``after`` (a long-poll served on the
    event loop, so waiting clients hold no worker thread)."""
    try:
        entry = await state.ring.wait_latest_async(after, wait) if wait else state.ring.latest()
    except TooManyWaiters as exc:
        raise HTTPException(429, str(exc), headers={"Retry-After": "1"}) from None
    if entry is None:
        status = state.capture.status()
        raise HTTPException(
            503, f"no frame yet from {status['spec'] or 'the source'} (state {status['state']}) {status['message']}".strip()
        )
    return frame_json(entry)


@router.get("/{frame_id}")
def frame_info(state: State, frame_id: FrameId) -> dict[str, Any]:
    return frame_json(state.entry(frame_id))


@router.get("/{frame_id}/color.png")
def color_png(state: State, frame_id: FrameId) -> Response:
    data = state.entry(frame_id).encoded("color.png", lambda f: encode_png(f.image))
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/{frame_id}/color.jpg")
def color_jpg(state: State, frame_id: FrameId) -> Response:
    """The colour image for the live view: JPEG quality 85 (color.png has the exact pixels)."""
    data = state.entry(frame_id).encoded("color.jpg", lambda f: encode_jpeg(f.image))
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/{frame_id}/disparity.png")
def disparity_png(state: State, frame_id: FrameId) -> Response:
    data = state.entry(frame_id).encoded("disparity.png", lambda f: encode_png(colorize_disparity(f.disparity)))
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.post("/{frame_id}/freeze")
def freeze(state: State, frame_id: FrameId) -> dict[str, Any]:
    entry = state.entry(frame_id)
    state.store.presave(entry.uid, entry.frame)  # a frozen frame is about to be measured: save it meanwhile
    return frame_json(state.ring.freeze(frame_id, True))


@router.delete("/{frame_id}/freeze")
def unfreeze(state: State, frame_id: FrameId) -> dict[str, Any]:
    state.entry(frame_id)
    return frame_json(state.ring.freeze(frame_id, False))
