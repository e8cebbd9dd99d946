"""``/api/shapes``: measuring a box, a height, a path or an area on a frame, stored in the history
beside the segments (``GET /api/measurements`` lists both; ``?kind=`` picks one)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response

from history.frame_file import as_stored
from measure import measure_shape

from service.deps import State
from service.routers.measurements import json_response, stored_frame
from service.schemas import ShapeIn, ShapeOut, json_doc
from service.shapes import draw_px
from service.state import ServiceState

router = APIRouter(prefix="/api", tags=["measurements"])


@router.post("/shapes", **json_doc(ShapeOut))
async def shapes(state: State, body: ShapeIn) -> Response:
    """Measure the shape ``kind`` clicked at ``points`` (px) on frame ``frame_id`` and store it, as
    ``POST /api/measure`` does a segment: a 200 means the measurement and its frame are on disk; an
    error status (404 / 410 for an unknown / evicted frame, 422 for clicks that do not fit the kind
    or that the core refuses, 429 while the workers are busy, 507 on a full disk) means nothing was
    stored."""
    return await state.measures.run(_shape, state, body)


def _shape(state: ServiceState, body: ShapeIn) -> Response:
    entry = state.ring.get(body.frame_id)
    frame = entry.frame
    # a box's sides are found in the colour image: measured on it as the history keeps it (JPEG), so
    # that re-measuring the stored frame (batch --from-history) gives this answer
    measured = as_stored(frame) if body.kind == "box" else frame
    result = measure_shape(measured, body.kind, body.points, body.on, body.options.to_options())
    record = state.store.add_shape(
        **stored_frame(state, entry), kind=body.kind, points=body.points, on=body.on, options=body.options.model_dump(),
        result=result.to_dict(), draw_px=draw_px(result, frame.camera),
    )  # returns once the measurement and its frame are on disk, as POST /api/measure's
    return json_response(record)
