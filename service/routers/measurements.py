"""``/api/measure`` and ``/api/measurements``: measuring a frame, and the stored history."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import JSONResponse, PlainTextResponse, Response

from measure import MeasureError, MeasureOptions, measure_distance
from measure.sequence import measure_sequence

from ..render import encode_png, frame_json, make_thumb
from ..schemas import AnnotationIn, MeasureIn
from ..state import ServiceState, State
from ..store import StoreError

router = APIRouter(prefix="/api", tags=["measurements"])


@router.post("/measure")
def measure(state: State, body: MeasureIn) -> dict[str, Any]:
    entry = state.entry(body.frame_id)
    frame = entry.frame
    h, w = frame.disparity.shape
    for name, (x, y) in (("p1", body.p1), ("p2", body.p2)):
        if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
            raise HTTPException(
                422, f"{name}=({x:g}, {y:g}) is outside the {w}x{h} image of frame {entry.id}; use 0<=x<={w - 1}, 0<=y<={h - 1}"
            )
    options = body.options.model_dump()
    used = [entry]
    if body.frames > 1:
        if body.options.method != "robust":
            raise HTTPException(422, f"frames={body.frames} needs the robust method (got {body.options.method!r}); use method 'robust' or frames=1")
        used = list(reversed(state.ring.before(entry.id, body.frames - 1))) + [entry]
    try:
        if body.frames > 1:
            result = measure_sequence([e.frame for e in used], body.p1, body.p2, MeasureOptions(**options))
        else:
            result = measure_distance(frame, body.p1, body.p2, MeasureOptions(**options))
    except MeasureError as exc:
        raise HTTPException(422, str(exc)) from None
    context = {"frame_index": replay["index"]} if isinstance(replay := frame.meta.get("replay"), dict) else {}
    if body.frames > 1:
        # The ids of the frames pooled, oldest first (the motion check may keep fewer than offered).
        context |= {"frames_requested": body.frames, "frame_ids": [e.id for e in used[len(used) - result.frames_used :]]}
    record = state.store.add(
        frame_id=entry.id,
        frame_uid=entry.uid,
        source=str(frame.meta.get("source", "")) or state.capture.spec,
        p1=body.p1,
        p2=body.p2,
        options=options,
        result=result.to_dict(),
        thumb=make_thumb(frame, body.p1, body.p2),
        context=context or None,
    )
    state.store.ensure_frame(entry.uid, frame)  # after the row exists: the writer drops frames nobody refers to
    return record


Units = Literal["m", "cm", "mm", "in"]


def _csv(state: ServiceState, units: str, request: Request) -> PlainTextResponse:
    return PlainTextResponse(
        state.store.csv(units, str(request.base_url)),
        media_type="text/csv",
        headers={"Content-Disposition": 'attachment; filename="depthruler-measurements.csv"'},
    )


@router.get("/measurements.csv")
def measurements_csv(state: State, request: Request, units: Units = "m") -> PlainTextResponse:
    """All measurements as CSV: lengths in ``units``, rounded to what each measurement supports."""
    return _csv(state, units, request)


@router.get("/measurements.json")
def measurements_json(state: State) -> JSONResponse:
    """All measurements, oldest first, as ``{"measurements": [...]}``: every stored field, including the
    per-sample arrays and, for a replay, ``frame_index``. ``depthruler export REC --mcap OUT
    --measurements FILE`` takes this file as it is."""
    return JSONResponse(
        {"measurements": list(reversed(state.store.list(limit=1_000_000)))},
        headers={"Content-Disposition": 'attachment; filename="depthruler-measurements.json"'},
    )


@router.get("/measurements", response_model=None)
def measurements(
    state: State, request: Request, format: Literal["json", "csv"] = "json", limit: Annotated[int, Query(ge=1)] = 1000
) -> Any:
    if format == "csv":
        return _csv(state, "m", request)
    return state.store.list(limit)


def _record(state: ServiceState, mid: int) -> dict[str, Any]:
    record = state.store.get(mid)
    if record is None:
        raise HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")
    return record


@router.get("/measurements/{mid}")
def measurement(state: State, mid: int) -> dict[str, Any]:
    return _record(state, mid)


@router.patch("/measurements/{mid}")
def annotate(state: State, mid: int, body: AnnotationIn) -> dict[str, Any]:
    """Name and/or note a measurement."""
    record = state.store.annotate(mid, body.name, body.note)
    if record is None:
        raise HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")
    return record


@router.delete("/measurements/{mid}")
def delete_measurement(state: State, mid: int) -> dict[str, Any]:
    if not state.store.delete(mid):
        raise HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")
    return {"deleted": mid}


@router.get("/measurements/{mid}/thumb.png")
def thumb(state: State, mid: int) -> Response:
    _record(state, mid)
    data = state.store.thumb(mid)
    if data is None:
        raise HTTPException(404, f"measurement {mid} has no thumbnail")
    return Response(data, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.get("/measurements/{mid}/color.png")
def measured_color(state: State, mid: int) -> Response:
    """The colour image of the saved frame a measurement was made on (the CSV's ``frame_url``)."""
    record = _record(state, mid)
    try:
        saved = state.store.frame(record["frame_uid"])
    except StoreError as exc:
        raise HTTPException(404, str(exc)) from None
    return Response(encode_png(saved.image), media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.post("/measurements/{mid}/open")
def reopen(state: State, mid: int) -> dict[str, Any]:
    """Put the saved frame of a measurement back into the ring (frozen) to view or re-measure it."""
    record = _record(state, mid)
    try:
        saved = state.store.frame(record["frame_uid"])
    except StoreError as exc:
        raise HTTPException(404, str(exc)) from None
    entry = state.ring.push(saved, frozen=True, uid=record["frame_uid"])
    return {"frame": frame_json(entry), "measurement": record}
