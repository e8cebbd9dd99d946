"""``/api/measure`` and ``/api/measurements``: measuring a frame, and the stored history."""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Path, Query, Request
from fastapi.responses import JSONResponse, PlainTextResponse, Response

from measure import MeasureError, MeasureOptions, measure_distance
from measure.sequence import measure_sequence

from service.render import encode_png, frame_json, make_thumb, png_from_jpeg, quarter
from service.schemas import (
    MAX_ID,
    AnnotationIn,
    DeletedOut,
    MeasureIn,
    MeasurementOut,
    MeasurementsOut,
    ReopenOut,
    json_doc,
    media_doc,
)
from service.state import ServiceState, State
from history.store import FrameDropped, StoreError, StoreFull

router = APIRouter(prefix="/api", tags=["measurements"])
MeasurementId = Annotated[int, Path(ge=0, le=MAX_ID)]


def _json(obj: Any) -> Response:
    """JSON encoded here, on the worker thread: FastAPI would encode a returned dict on the event
    loop, where a record with its samples stalls every other request for a millisecond or more."""
    return Response(json.dumps(obj, separators=(",", ":"), allow_nan=False).encode(), media_type="application/json")


@router.post("/measure", **json_doc(MeasurementOut))
def measure(state: State, body: MeasureIn) -> Response:
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
    try:
        record = state.store.add(
            frame_id=entry.id,
            frame_uid=entry.uid,
            frame=frame,
            source=str(frame.meta.get("source", "")) or state.capture.spec,
            p1=body.p1,
            p2=body.p2,
            options=options,
            result=result.to_dict(),
            context=context or None,
        )  # returns once the measurement and its frame are on disk; the thumbnail is drawn on request
    except StoreFull as exc:
        raise HTTPException(507, str(exc)) from None
    except StoreError as exc:
        raise HTTPException(500, str(exc)) from None
    return _json(record)


Units = Literal["m", "cm", "mm", "in"]


def _csv(state: ServiceState, units: str, request: Request) -> PlainTextResponse:
    return PlainTextResponse(
        state.store.csv(units, str(request.base_url)),
        media_type="text/csv",
        headers={"Content-Disposition": 'attachment; filename="depthruler-measurements.csv"'},
    )


@router.get("/measurements.csv", **media_doc("text/csv", text=True))
def measurements_csv(state: State, request: Request, units: Units = "m") -> PlainTextResponse:
    """All measurements as CSV: lengths in ``units``, rounded to what each measurement supports."""
    return _csv(state, units, request)


@router.get("/measurements.json", **json_doc(MeasurementsOut))
def measurements_json(state: State) -> JSONResponse:
    """All measurements, oldest first, as ``{"measurements": [...]}``: every stored field, including the
    per-sample arrays and, for a replay, ``frame_index``. ``depthruler export REC --mcap OUT
    --measurements FILE`` takes this file as it is."""
    return JSONResponse(
        {"measurements": list(reversed(state.store.list(limit=1_000_000)))},
        headers={"Content-Disposition": 'attachment; filename="depthruler-measurements.json"'},
    )


@router.get("/measurements", **json_doc(list[MeasurementOut], csv=True))
def measurements(
    state: State,
    request: Request,
    format: Literal["json", "csv"] = "json",
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    before: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
) -> Response:
    """The history, newest first, slim: every field but the per-sample arrays (``samples_px``,
    ``support``: ``GET /api/measurements/{id}`` has them). Pages: ``limit`` records with an id
    below ``before`` (pass the last id of the previous page). Encoded here, on a worker thread,
    not on the event loop."""
    if format == "csv":
        return _csv(state, "m", request)
    return Response(state.store.list_slim_json(limit, before), media_type="application/json")


def _no_measurement(mid: int) -> HTTPException:
    return HTTPException(404, f"no measurement {mid}; GET /api/measurements lists them")


def _record(state: ServiceState, mid: int) -> dict[str, Any]:
    record = state.store.get(mid)
    if record is None:
        raise _no_measurement(mid)
    return record


@router.get("/measurements/{mid}", **json_doc(MeasurementOut))
def measurement(state: State, mid: MeasurementId) -> Response:
    """The full record, with the per-sample arrays."""
    return _json(_record(state, mid))


@router.patch("/measurements/{mid}", **json_doc(MeasurementOut))
def annotate(state: State, mid: MeasurementId, body: AnnotationIn) -> dict[str, Any]:
    """Name and/or note a measurement."""
    record = state.store.annotate(mid, body.name, body.note)
    if record is None:
        raise _no_measurement(mid)
    return record


@router.delete("/measurements/{mid}", **json_doc(DeletedOut))
def delete_measurement(state: State, mid: MeasurementId) -> dict[str, Any]:
    if not state.store.delete(mid):
        raise _no_measurement(mid)
    return {"deleted": mid}


def _thumb(state: ServiceState, mid: int) -> bytes:
    """The measurement's thumbnail, drawn on first request from its frame (still in the ring, else
    its saved file) and kept in memory."""
    where = state.store.segment(mid)
    if where is None:
        raise _no_measurement(mid)
    data = state.store.thumb(mid)
    if data is None:
        uid, p1, p2 = where
        entry = state.ring.find(uid)  # the frame is usually still in the ring: no file to read and decode
        try:
            image, width = (quarter(entry.frame.image), entry.frame.image.shape[1]) if entry else state.store.preview(uid)
        except StoreError as exc:
            raise HTTPException(404, f"measurement {mid} has no thumbnail: {exc}") from None
        data = make_thumb(image, width, p1, p2)
        state.store.set_thumb(mid, data)
    return data


@router.get("/measurements/{mid}/thumb.jpg", **media_doc("image/jpeg", "image/png"))
def thumb_jpg(state: State, mid: MeasurementId) -> Response:
    data = _thumb(state, mid)
    media = "image/png" if data.startswith(b"\x89PNG") else "image/jpeg"  # histories from before kept PNG
    return Response(data, media_type=media, headers={"Cache-Control": "private, max-age=86400"})


@router.get("/measurements/{mid}/thumb.png", **media_doc("image/png"))
def thumb(state: State, mid: MeasurementId) -> Response:
    data = _thumb(state, mid)
    png = data if data.startswith(b"\x89PNG") else png_from_jpeg(data)
    return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.get("/measurements/{mid}/color.png", **media_doc("image/png"))
def measured_color(state: State, mid: MeasurementId) -> Response:
    """The colour image of the saved frame a measurement was made on (the CSV's ``frame_url``)."""
    record = _record(state, mid)
    try:
        saved = state.store.frame(record["frame_uid"])
    except StoreError as exc:
        raise HTTPException(404, str(exc)) from None
    return Response(encode_png(saved.image), media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.post("/measurements/{mid}/open", **json_doc(ReopenOut))
def reopen(state: State, mid: MeasurementId) -> dict[str, Any]:
    """Put the saved frame of a measurement back into the ring (frozen) to view or re-measure it."""
    record = _record(state, mid)
    try:
        saved = state.store.frame(record["frame_uid"])
    except FrameDropped as exc:
        raise HTTPException(410, str(exc)) from None
    except StoreError as exc:
        raise HTTPException(404, str(exc)) from None
    entry = state.ring.push(saved, frozen=True, uid=record["frame_uid"])
    return {"frame": frame_json(entry), "measurement": record}


@router.post("/measurements/{mid}/pin", **json_doc(MeasurementOut))
def pin(state: State, mid: MeasurementId) -> dict[str, Any]:
    """Keep this measurement's frame whatever the history cap (``--history-max-gb``)."""
    _record(state, mid)
    return state.store.pin(mid, True) or _record(state, mid)


@router.delete("/measurements/{mid}/pin", **json_doc(MeasurementOut))
def unpin(state: State, mid: MeasurementId) -> dict[str, Any]:
    _record(state, mid)
    return state.store.pin(mid, False) or _record(state, mid)
