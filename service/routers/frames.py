"""``/api/frames``: the live and frozen frames of the ring buffer, their images, freezing."""

from __future__ import annotations

import asyncio
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import Response

from service.deps import FrameDep, State
from service.frame_errors import NoConfidence
from service.render import (
    colorize_disparity,
    confidence_image,
    disparity_range,
    LIVE_JPEG,
    encode_png,
    frame_json,
    live_jpeg,
    turbo_colors,
)
from service.schemas import MAX_ID, DepthOut, DepthScaleOut, FrameOut, json_doc, media_doc

router = APIRouter(prefix="/api/frames", tags=["frames"])


@router.get("/latest", **json_doc(FrameOut))
async def latest(
    state: State, after: Annotated[int, Query(ge=0, le=MAX_ID)] = 0, wait: Annotated[float, Query(ge=0, le=10)] = 0.0
) -> dict[str, Any]:
    """The newest frame; with ``wait``, the first one newer than ``after`` (a long-poll served on the
    event loop, so waiting clients hold no worker thread)."""
    # after a wait with nothing newer (a paused or ended replay) the newest frame is still the answer
    entry = (await state.ring.wait_latest_async(after, wait) if wait else None) or state.ring.latest()
    if entry is None:
        status = state.capture.status()
        raise HTTPException(
            503, f"no frame yet from {status['spec'] or 'the source'} (state {status['state']}) {status['message']}".strip()
        )
    state.ring.mark_viewed(entry.id)  # the page shows it next and may freeze it after the ring moved on
    return frame_json(entry)


@router.get("/{frame_id}", **json_doc(FrameOut))
def frame_info(entry: FrameDep) -> dict[str, Any]:
    return frame_json(entry)


@router.get("/{frame_id}/color.png", **media_doc("image/png"))
def color_png(entry: FrameDep) -> Response:
    data = entry.encoded("color.png", lambda f: encode_png(f.image), image_only=True)
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/{frame_id}/color.jpg", **media_doc("image/jpeg"))
async def color_jpg(state: State, entry: FrameDep) -> Response:
    """The colour image for the live view: JPEG quality 85 (color.png has the exact pixels). Answered
    on the event loop when the JPEG is made already (the capture thread makes it before it shows the
    frame while a page follows every frame), else encoded on the live view's own thread, never queued
    behind the routes on the general thread pool."""
    data = entry.cached(LIVE_JPEG) or await asyncio.get_running_loop().run_in_executor(state.live_images, live_jpeg, entry)
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/{frame_id}/disparity.png", **media_doc("image/png"))
def disparity_png(entry: FrameDep) -> Response:
    data = entry.encoded("disparity.png", lambda f: encode_png(colorize_disparity(f.disparity)))
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


# Which sources fill Frame.confidence (docs/decisions/matcher-confidence.md "Per source").
CONFIDENCE_SOURCES = (
    "SGBM sources (v4l2:, video:, middlebury:?disparity=sgbm, sim:?mode=stereo), DepthAI with align=left "
    "and the simulator's sensor model (unless confidence=false) fill one"
)


@router.get("/{frame_id}/confidence.png", **media_doc("image/png"))
def confidence_png(entry: FrameDep) -> Response:
    """The frame's matcher confidence as a grey PNG of the frame's size: round(c * 255), black = no
    support (0), white = fully supported (1). 404 where the frame's source gives no confidence."""
    if entry.packed.confidence is None:
        source = str(entry.packed.meta.get("source", "")) or "unknown"
        raise NoConfidence(f"frame {entry.id} has no confidence map: its source ({source}) gives none; {CONFIDENCE_SOURCES}")
    data = entry.encoded("confidence.png", lambda f: encode_png(confidence_image(f.confidence)))
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/{frame_id}/depth", **json_doc(DepthOut))
def depth_at(
    entry: FrameDep, x: Annotated[float, Query(allow_inf_nan=False)], y: Annotated[float, Query(allow_inf_nan=False)]
) -> dict[str, Any]:
    """Depth (m) and disparity (px) at the pixel nearest to (x, y), pixel-centre convention; ``None``
    where the disparity has no data. Depth is ``Frame.depth()``: Z = fx * baseline / (d + doffs)."""
    frame, frame_id = entry.frame, entry.id
    h, w = frame.disparity.shape
    if not (-0.5 <= x < w - 0.5 and -0.5 <= y < h - 0.5):
        raise HTTPException(
            422, f"({x:g}, {y:g}) is outside the {w}x{h} image of frame {frame_id}; use 0<=x<={w - 1}, 0<=y<={h - 1}"
        )
    col, row = int(round(x)), int(round(y))
    d = float(frame.disparity[row, col])
    shifted = d + frame.doffs  # Frame.depth() at one pixel, in the same float64 steps (it maps the whole frame)
    z = frame.camera.fx * frame.baseline_m / shifted if shifted > 0 else float("nan")
    return {
        "frame_id": frame_id,
        "x": col,
        "y": row,
        "disparity_px": d if np.isfinite(d) else None,
        "depth_m": z if np.isfinite(z) else None,
    }


@router.get("/{frame_id}/depth-scale", **json_doc(DepthScaleOut))
def depth_scale(entry: FrameDep) -> dict[str, Any]:
    """What the colours of ``disparity.png`` mean: the disparity range (px) at the ends of the colour
    map, the same range as depth (m), and ``fx_baseline`` and ``doffs`` to place any depth on it."""
    frame = entry.frame
    span = disparity_range(frame.disparity)
    fb = frame.camera.fx * frame.baseline_m

    def z(d: float) -> float | None:
        return fb / (d + frame.doffs) if d + frame.doffs > 0 else None

    return {
        "frame_id": entry.id,
        "disparity_px": list(span) if span else None,
        "depth_m": [z(span[1]), z(span[0])] if span else None,  # near (high disparity) first
        "fx_baseline": fb,
        "doffs": frame.doffs,
        "colors": turbo_colors(),
    }


@router.post("/{frame_id}/freeze", **json_doc(FrameOut))
def freeze(state: State, entry: FrameDep) -> dict[str, Any]:
    entry.packed.keep_image()  # measured, saved and drawn next: made once, not for each of them
    state.store.presave(entry.uid, entry.frame)  # a frozen frame is about to be measured: save it meanwhile
    return frame_json(state.ring.freeze(entry.id, True))


@router.delete("/{frame_id}/freeze", **json_doc(FrameOut))
def unfreeze(state: State, entry: FrameDep) -> dict[str, Any]:
    return frame_json(state.ring.freeze(entry.id, False))
