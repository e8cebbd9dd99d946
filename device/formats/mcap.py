"""Export a recording to MCAP with Foxglove schemas, so it opens in Foxglove and Rerun.

Topics (all images in the ``camera`` frame, the colour camera the disparity is registered to):

- ``/camera/color``        foxglove.RawImage, ``bgr8``, lossless (the recorded colour bytes)
- ``/camera/depth``        foxglove.RawImage, ``32FC1``: depth in metres, NaN where no disparity
                           (the ROS REP 118 convention both viewers understand). Disparity follows
                           exactly: ``d = fx * baseline_m / Z - doffs`` with the values in metadata.
- ``/camera/confidence``   foxglove.RawImage, ``mono8`` = round(c * 255), when recorded
- ``/camera/calibration``  foxglove.CameraCalibration (K, P, R = I, no distortion: the images are rectified)
- ``/measurements``        JSON (jsonschema): the Measurement dicts given, one message each
- ``/camera/annotations``  foxglove.ImageAnnotations: each measurement's segment and length on the image,
                           or a shape's outline (its ``draw_px``) and value (a box's three dimensions)

Metadata record ``depthruler``: baseline_m, doffs, the source and the recording's manifest.
Message times: the recorded timestamps, shifted so the first frame is at the recording's creation
time (device clocks are often seconds since boot); when timestamps do not increase, frames are
spaced at the source fps (or 10 Hz).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from device.errors import RecordingError
from device.formats.recording import Recording, jsonable, open_recording
from measure.shape_types import outlines

TOPIC_COLOR = "/camera/color"
TOPIC_DEPTH = "/camera/depth"
TOPIC_CONFIDENCE = "/camera/confidence"
TOPIC_CALIBRATION = "/camera/calibration"
TOPIC_MEASUREMENTS = "/measurements"
TOPIC_ANNOTATIONS = "/camera/annotations"
FRAME_ID = "camera"
_FALLBACK_FPS = 10.0

MEASUREMENT_SCHEMA = {
    "title": "depthruler.Measurement",
    "type": "object",
    "properties": {
        "frame_index": {"type": "integer"},
        "distance_m": {"type": ["number", "null"]},
        "uncertainty_m": {"type": ["number", "null"]},
        "method": {"type": "string"},
        "fit": {"type": "string"},
        "p1": {"type": "array", "items": {"type": "number"}},
        "p2": {"type": "array", "items": {"type": "number"}},
        "p1_m": {"type": "array", "items": {"type": ["number", "null"]}},
        "p2_m": {"type": "array", "items": {"type": ["number", "null"]}},
    },
}


def load_measurements(path: str | Path) -> list[dict[str, Any]]:
    """Measurement dicts from a JSON file: a list, or an object with a "measurements" list.

    Each dict has Measurement.to_dict() fields; optional ``frame_index`` (which frame it was made
    on, default 0) and ``p1``/``p2`` (the clicked pixels, else the first/last sample is drawn).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{path} cannot be read as JSON ({exc}); give a JSON list of measurement objects") from exc
    if isinstance(data, Mapping):
        data = data.get("measurements")
    if not isinstance(data, list) or not all(isinstance(m, Mapping) for m in data):
        raise RecordingError(f"{path} must hold a JSON list of measurement objects (or {{\"measurements\": [...]}})")
    return [dict(m) for m in data]


def _frame_times_ns(rec: Recording) -> list[int]:
    base = float(rec.manifest.get("created_unix") or 0.0)
    ts = rec.timestamps
    if len(ts) > 1 and np.all(np.diff(ts) > 0):
        offsets = ts - ts[0]
    else:
        fps = rec.source.fps if rec.source.fps > 0 else _FALLBACK_FPS
        offsets = np.arange(len(ts)) / fps
    base_ns = int(round(base * 1e9))  # add in integers: a float of ~1.7e18 ns keeps only ~256 ns steps
    return [base_ns + int(round(float(o) * 1e9)) for o in offsets]


def _stamp(msg: Any, t_ns: int) -> None:
    msg.timestamp.seconds = t_ns // 1_000_000_000
    msg.timestamp.nanos = t_ns % 1_000_000_000


def _endpoints(m: Mapping[str, Any]) -> tuple[tuple[float, float], tuple[float, float]] | None:
    if "p1" in m and "p2" in m:
        return (float(m["p1"][0]), float(m["p1"][1])), (float(m["p2"][0]), float(m["p2"][1]))
    samples = m.get("samples_px") or []
    if len(samples) >= 2:
        return (float(samples[0][0]), float(samples[0][1])), (float(samples[-1][0]), float(samples[-1][1]))
    return None


def _number(v: Any, unit: str) -> str:
    return f"{v:.3f} {unit}" if isinstance(v, (int, float)) and math.isfinite(v) else ""


def _label(m: Mapping[str, Any]) -> str:
    """A measurement's text on the image: a segment's distance, a shape's value, each ± its 1σ where
    known; a box's three dimensions and its verdict."""
    kind = str(m.get("kind", "segment"))
    if kind == "box":
        dims = [_number(v, "").strip() or "?" for v in m.get("dimensions_m") or [None] * 3]
        return f"{' x '.join(dims)} m" + (f" ({m['quality']})" if m.get("quality") else "")
    if kind == "segment":
        value, sigma, unit = m.get("distance_m"), m.get("uncertainty_m"), "m"
    else:
        value, sigma, unit = m.get("value"), m.get("uncertainty"), "m²" if m.get("unit") == "m2" else "m"
    label = _number(value, unit) or f"no {'distance' if kind == 'segment' else kind}"
    return label + (f" ± {sigma:.3f}" if _number(sigma, unit) else "")


def _drawing(m: Mapping[str, Any]) -> tuple[list[tuple[list[list[float]], bool]], str] | None:
    """The polylines (px, closed or not) and the label of measurement ``m``: a segment's line between
    its clicks (or first and last samples), a shape's outline from its ``draw_px``; None when ``m``
    says nothing to draw."""
    kind = str(m.get("kind", "segment"))
    if kind == "segment":
        ends = _endpoints(m)
        lines = [([list(ends[0]), list(ends[1])], False)] if ends else []
    else:
        lines = [line for line in outlines(kind, m.get("draw_px") or []) if len(line[0]) >= 2]
    return (lines, _label(m)) if lines else None


def _annotation(t_ns: int, lines: list[tuple[list[list[float]], bool]], label: str) -> Any:
    """foxglove.ImageAnnotations: ``lines`` in yellow, ``label`` on a dark box at the first line's middle."""
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation

    ann = ImageAnnotations()
    _stamp(ann, t_ns)
    for points, closed in lines:
        line = PointsAnnotation(type=PointsAnnotation.LINE_LOOP if closed else PointsAnnotation.LINE_STRIP, thickness=3.0)
        _stamp(line, t_ns)
        for x, y in points:
            line.points.append(Point2(x=x, y=y))
        line.outline_color.r, line.outline_color.g, line.outline_color.b, line.outline_color.a = 1.0, 0.85, 0.0, 1.0
        ann.points.append(line)
    text = TextAnnotation(text=label, font_size=18.0)
    _stamp(text, t_ns)
    first = np.asarray(lines[0][0], dtype=float)
    text.position.x, text.position.y = (float(v) for v in (first.mean(0) if lines[0][1] else (first[0] + first[-1]) / 2))
    text.text_color.r = text.text_color.g = text.text_color.b = text.text_color.a = 1.0
    text.background_color.a = 0.6
    ann.texts.append(text)
    return ann


def export_mcap(
    recording: str | Path | Recording,
    out: str | Path,
    *,
    measurements: Sequence[Mapping[str, Any]] = (),
    overwrite: bool = False,
) -> dict[str, int]:
    """Write ``recording`` to the MCAP file ``out``; returns the number of messages per topic.

    The file is written beside ``out`` and renamed into place when complete, so a failed export
    never leaves a half-written file under the requested name.
    """
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from mcap.writer import CompressionType, Writer
    from mcap_protobuf.schema import register_schema

    from device.formats.recording import encode_confidence

    rec = recording if isinstance(recording, Recording) else open_recording(recording)
    out = Path(out)
    if out.exists() and not overwrite:
        raise RecordingError(f"{out} already exists; pass --overwrite to replace it or choose another file")
    if len(rec) == 0:
        raise RecordingError(f"{rec.path} has no complete frame to export")
    times = _frame_times_ns(rec)
    counts: dict[str, int] = {}
    tmp = out.with_name(f".{out.name}.partial")
    try:
        with open(tmp, "wb") as stream:
            writer = Writer(stream, compression=CompressionType.ZSTD)
            writer.start(profile="", library="depthruler")
            channels: dict[str, int] = {}

            def channel(topic: str, cls: Any) -> int:
                if topic not in channels:
                    channels[topic] = writer.register_channel(topic, "protobuf", register_schema(writer, cls))
                return channels[topic]

            def put(topic: str, msg: Any, t_ns: int) -> None:
                writer.add_message(channel(topic, type(msg)), t_ns, msg.SerializeToString(), t_ns, counts.get(topic, 0))
                counts[topic] = counts.get(topic, 0) + 1

            writer.add_metadata(
                "depthruler",
                {
                    "baseline_m": repr(rec.baseline_m),
                    "doffs": repr(rec.doffs),
                    "depth_topic": f"{TOPIC_DEPTH}: 32FC1 metres, NaN invalid; disparity = fx * baseline_m / Z - doffs",
                    "source": json.dumps(rec.manifest.get("source")),
                    "manifest": json.dumps(rec.manifest),
                },
            )
            for i, t_ns in enumerate(times):
                frame = rec.frame(i)
                cam = frame.camera
                h, w = frame.shape
                img = RawImage(frame_id=FRAME_ID, width=w, height=h, encoding="bgr8", step=3 * w, data=frame.image.tobytes())
                _stamp(img, t_ns)
                put(TOPIC_COLOR, img, t_ns)
                depth = frame.depth().astype("<f4")
                dimg = RawImage(frame_id=FRAME_ID, width=w, height=h, encoding="32FC1", step=4 * w, data=depth.tobytes())
                _stamp(dimg, t_ns)
                put(TOPIC_DEPTH, dimg, t_ns)
                if frame.confidence is not None:
                    cimg = RawImage(
                        frame_id=FRAME_ID, width=w, height=h, encoding="mono8", step=w, data=encode_confidence(frame.confidence).tobytes()
                    )
                    _stamp(cimg, t_ns)
                    put(TOPIC_CONFIDENCE, cimg, t_ns)
                calib = CameraCalibration(
                    frame_id=FRAME_ID,
                    width=cam.width,
                    height=cam.height,
                    distortion_model="plumb_bob",
                    D=[0.0] * 5,
                    K=[cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0],
                    R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                    P=[cam.fx, 0.0, cam.cx, 0.0, 0.0, cam.fy, cam.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
                )
                _stamp(calib, t_ns)
                put(TOPIC_CALIBRATION, calib, t_ns)
            if measurements:
                schema_id = writer.register_schema(
                    "depthruler.Measurement", "jsonschema", json.dumps(MEASUREMENT_SCHEMA).encode()
                )
                meas_channel = writer.register_channel(TOPIC_MEASUREMENTS, "json", schema_id)
                for k, m in enumerate(measurements):
                    idx = int(m.get("frame_index", m.get("frame", 0)) or 0)
                    if not 0 <= idx < len(times):
                        raise RecordingError(
                            f"measurement {k} refers to frame {idx}, but {rec.path} has frames 0..{len(times) - 1}; fix its frame_index"
                        )
                    t_ns = times[idx]
                    try:
                        body = jsonable({**m, "frame_index": idx})
                    except TypeError as exc:
                        raise RecordingError(f"measurement {k} holds a value JSON cannot carry ({exc}); give plain numbers, strings and lists") from exc
                    writer.add_message(meas_channel, t_ns, json.dumps(body, allow_nan=False).encode(), t_ns, k)
                    counts[TOPIC_MEASUREMENTS] = counts.get(TOPIC_MEASUREMENTS, 0) + 1
                    drawn = _drawing(m)
                    if drawn is not None:
                        put(TOPIC_ANNOTATIONS, _annotation(t_ns, *drawn), t_ns)
            writer.finish()
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, out)
    except OSError as exc:
        raise RecordingError(f"cannot write {out}: {exc.strerror or exc}; check the path and free space") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return counts

