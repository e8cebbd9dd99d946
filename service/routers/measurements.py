"""``/api/measure`` and ``/api/measurements``: measuring a frame, and the stored history."""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request
from fastapi.responses import Response, StreamingResponse

from measure import measure_distance, measure_sequence, outlines, weak_stretches

from history.export import csv_chunks, json_chunks

from service.deps import MeasurementDep, MeasurementId, State
from service.frames import RingFrame
from service.provenance import provenance
from service.render import encode_png, frame_json, make_thumb, png_from_jpeg, quarter
from service.schemas import (
    MAX_ID,
    AnnotationIn,
    AnyMeasurementOut,
    DeletedOut,
    MeasureIn,
    MeasurementOut,
    MeasurementsOut,
    ReopenOut,
    json_doc,
    media_doc,
)
from service.state import ServiceState

router = APIRouter(prefix="/api", tags=["measurements"])


def json_response(obj: Any) -> Response:
    """JSON encoded here, on the worker thread: FastAPI would encode a returned dict on the event
    loop, where a record with its samples stalls every other request for a millisecond or more."""
    return Response(json.dumps(obj, separators=(",", ":"), allow_nan=False).encode(), media_type="application/json")


@router.post("/measure", **json_doc(MeasurementOut))
async def measure(state: State, body: MeasureIn) -> Response:
    """Measure between ``p1`` and ``p2`` (px) on frame ``frame_id`` and store it: a 200 means the
    measurement and its frame are on disk; an error status means nothing was stored. Runs on the
    measurement workers (as many as the CPU has cores, a short queue): 429 with ``Retry-After``
    when they are all busy, so that the live view and health never wait behind measurements."""
    return await state.measures.run(_measure, state, body)


def _measure(state: ServiceState, body: MeasureIn) -> Response:
    entry = state.ring.get(body.frame_id)
    frame = entry.frame
    options, core = body.options.model_dump(), body.options.to_options()
    used = [entry]
    if body.frames > 1:
        used = list(reversed(state.ring.before(entry.id, body.frames - 1))) + [entry]
        result = measure_sequence([e.frame for e in used], body.p1, body.p2, core)
    else:
        result = measure_distance(frame, body.p1, body.p2, core)
    # where along the segment the clicked frame's matcher had weak support, for the page to mark
    weak = {"weak_stretches": weak_stretches(frame.confidence, body.p1, body.p2).round(4).tolist()}
    stored = stored_frame(state, entry)
    if body.frames > 1:
        # The ids of the frames pooled, oldest first (the motion check may keep fewer than offered).
        stored["context"] |= {"frames_requested": body.frames, "frame_ids": [e.id for e in used[len(used) - result.frames_used :]]}
    record = state.store.add(
        **stored, p1=body.p1, p2=body.p2, options=options, result=result.to_dict() | weak
    )  # returns once the measurement and its frame are on disk; the thumbnail is drawn on request
    return json_response(record)


def stored_frame(state: ServiceState, entry: RingFrame) -> dict[str, Any]:
    """The arguments of ``Store.add`` / ``Store.add_shape`` that say which frame was measured: its
    ring id and uid, the frame, the source's description and the request's context (provenance)."""
    source, context = provenance(entry.frame, state.capture.info, state.capture.spec)
    return {"frame_id": entry.id, "frame_uid": entry.uid, "frame": entry.frame, "source": source, "context": context}


Units = Literal["m", "cm", "mm", "in"]
Kind = Literal["segment", "box", "height", "path", "area"]


def _attachment(name: str) -> dict[str, str]:
    return {"Content-Disposition": f'attachment; filename="{name}"'}


def _csv(state: ServiceState, units: str, request: Request) -> StreamingResponse:
    """Streamed, a batch of rows at a time, each pulled on a worker thread (a sync iterator), so
    neither the event loop nor the memory holds the whole history."""
    chunks = csv_chunks(state.store.batches(), units, str(request.base_url))
    return StreamingResponse(chunks, media_type="text/csv", headers=_attachment("depthruler-measurements.csv"))


@router.get("/measurements.csv", **media_doc("text/csv", text=True))
def measurements_csv(state: State, request: Request, units: Units = "m") -> StreamingResponse:
    """All measurements as CSV: lengths in ``units``, rounded to what each measurement supports."""
    return _csv(state, units, request)


@router.get("/measurements.json", **json_doc(MeasurementsOut))
def measurements_json(state: State) -> StreamingResponse:
    """All measurements, oldest first, as ``{"measurements": [...]}``: every stored field, including the
    per-sample arrays and, for a replay, ``frame_index``. ``depthruler export REC --mcap OUT
    --measurements FILE`` takes this file as it is. Streamed like the CSV."""
    chunks = json_chunks(state.store.batches(arrays=True))
    return StreamingResponse(chunks, media_type="application/json", headers=_attachment("depthruler-measurements.json"))


@router.get("/measurements", **json_doc(list[AnyMeasurementOut], csv=True))
def measurements(
    state: State,
    request: Request,
    format: Literal["json", "csv"] = "json",
    limit: Annotated[int, Query(ge=1, le=10_000)] = 1000,
    before: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    kind: Kind | None = None,
) -> Response:
    """The history, newest first, slim: every field but the per-sample arrays (``samples_px``,
    ``support``: ``GET /api/measurements/{id}`` has them). Pages: ``limit`` records with an id
    below ``before`` (pass the last id of the previous page); ``kind`` keeps one kind ("segment",
    "box", "height", "path", "area"). Encoded here, on a worker thread, not on the event loop."""
    if format == "csv":
        return _csv(state, "m", request)
    return Response(state.store.list_slim_json(limit, before, kind), media_type="application/json")


@router.get("/measurements/{mid}", **json_doc(AnyMeasurementOut))
def measurement(record: MeasurementDep) -> Response:
    """The full record, with the per-sample arrays."""
    return json_response(record)


@router.patch("/measurements/{mid}", **json_doc(AnyMeasurementOut))
def annotate(state: State, mid: MeasurementId, body: AnnotationIn) -> dict[str, Any]:
    """Name and/or note a measurement (works on a full disk: the history keeps a reserve for it)."""
    return state.store.annotate(mid, body.name, body.note)


@router.delete("/measurements/{mid}", **json_doc(DeletedOut))
def delete_measurement(state: State, mid: MeasurementId) -> dict[str, Any]:
    """Delete a measurement, and its saved frame once no other measurement uses it (works on a full disk)."""
    state.store.delete(mid)
    return {"deleted": mid}


def _thumb(state: ServiceState, mid: int) -> bytes:
    """The measurement's thumbnail, drawn on first request from its frame (still in the ring, else
    its saved file) and kept in memory."""
    uid, kind, points = state.store.drawing(mid)
    data = state.store.thumb(mid)
    if data is None:
        entry = state.ring.find(uid)  # the frame is usually still in the ring: no file to read and decode
        full = entry.packed.image if entry else None  # made again for a frame whose image the ring does not hold
        image, width = (quarter(full), full.shape[1]) if full is not None else state.store.preview(uid)
        data = make_thumb(image, width, outlines(kind, points))
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
def measured_color(state: State, record: MeasurementDep) -> Response:
    """The colour image of the saved frame a measurement was made on (the CSV's ``frame_url``)."""
    saved = state.store.frame(record["frame_uid"])
    return Response(encode_png(saved.image), media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.post("/measurements/{mid}/open", **json_doc(ReopenOut))
def reopen(state: State, record: MeasurementDep) -> dict[str, Any]:
    """Put the saved frame of a measurement back into the ring (frozen) to view or re-measure it."""
    saved = state.store.frame(record["frame_uid"])
    entry = state.ring.push(saved, frozen=True, uid=record["frame_uid"])
    return {"frame": frame_json(entry), "measurement": record}


@router.post("/measurements/{mid}/pin", **json_doc(AnyMeasurementOut))
def pin(state: State, mid: MeasurementId) -> dict[str, Any]:
    """Keep this measurement's frame whatever the history cap (``--history-max-gb``)."""
    return state.store.pin(mid, True)


@router.delete("/measurements/{mid}/pin", **json_doc(AnyMeasurementOut))
def unpin(state: State, mid: MeasurementId) -> dict[str, Any]:
    return state.store.pin(mid, False)
