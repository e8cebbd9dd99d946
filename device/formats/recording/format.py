"""The recording format: constants, the 16-bit disparity and 8-bit confidence codes, PNG/.npy
encoding, the durable file operations and the JSON form of meta (layout in ``device.formats.recording``)."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, PinholeCamera

from device.base import SourceInfo
from device.errors import RecordingError, SourceEnded, SourceNotFound

FORMAT = "depthruler-recording"
FORMAT_VERSION = 1
DISPARITY_SCALE = 64
MAX_DISPARITY_CODE = 65535
MANIFEST = "manifest.json"
FRAMES = "frames.jsonl"
RAW_KEYS = ("raw_left", "raw_right")
_MANIFEST_INTERVAL_S = 1.0
_PNG_COMPRESSION = 1  # zlib level 1: lossless like any level, ~2x faster than OpenCV's default 3 for ~3 % more bytes
_SAFE_KEY = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_SMALL_ARRAY = 64  # arrays up to this many elements go into the JSON meta as lists


class EndOfRecording(SourceEnded):
    """A replay reached the last frame (and was not asked to loop)."""


class RecordingNotFound(RecordingError, SourceNotFound):
    """The path given is not there or holds no recording."""


# ---------------------------------------------------------------------------------------------
# encoding of the arrays


def encode_disparity(disparity: np.ndarray) -> tuple[np.ndarray, int]:
    """Disparity (float px, NaN invalid) -> (uint16 code = round(d * 64), 0 = invalid; pixels dropped).

    Raises RecordingError when a disparity of 1024 px or more cannot be stored. Negative values and
    values below 1/128 px (which round to the invalid code) become invalid and are counted.
    """
    d = np.asarray(disparity, dtype=np.float32)
    finite = np.isfinite(d)
    scaled = np.where(finite, d, 0.0).astype(np.float64) * DISPARITY_SCALE
    code = np.rint(scaled)
    too_big = code > MAX_DISPARITY_CODE
    if too_big.any():
        raise RecordingError(
            f"{int(too_big.sum())} pixels have disparity >= {MAX_DISPARITY_CODE / DISPARITY_SCALE:.2f} px "
            f"(largest {float(d[too_big].max()):.1f} px), beyond what the 16-bit 1/64-px format stores; "
            "record at a lower resolution or a larger working distance"
        )
    keep = finite & (code >= 1)
    out = np.zeros(d.shape, dtype=np.uint16)
    out[keep] = code[keep].astype(np.uint16)
    dropped = int(np.count_nonzero(finite & ~keep) + np.count_nonzero(np.isinf(d)))
    return out, dropped


def decode_disparity(code: np.ndarray) -> np.ndarray:
    """uint16 code -> float32 disparity in pixels, NaN where the code is 0."""
    d = code.astype(np.float32) / np.float32(DISPARITY_SCALE)
    d[code == 0] = np.nan
    return d


def encode_confidence(confidence: np.ndarray) -> np.ndarray:
    c = np.nan_to_num(np.asarray(confidence, dtype=np.float32), nan=0.0)
    return np.rint(np.clip(c, 0.0, 1.0) * 255.0).astype(np.uint8)


def decode_confidence(code: np.ndarray) -> np.ndarray:
    return code.astype(np.float32) / np.float32(255.0)


def _encode_png(image: np.ndarray, row_filter: str = "sub") -> bytes:
    """Lossless PNG. A fixed row filter (instead of libpng's adaptive choice) roughly halves the
    encoding time at 720p for ~5 % more bytes: "sub" suits photos, "up" smooth disparity maps."""
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, _PNG_COMPRESSION]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP if row_filter == "up" else cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buf = cv2.imencode(".png", image, params)
    if not ok:
        raise RecordingError(f"OpenCV could not PNG-encode a {image.shape} {image.dtype} image")
    return buf.tobytes()


def _encode_smooth_png(image: np.ndarray) -> bytes:
    return _encode_png(image, "up")


def _encode_npy(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(array), allow_pickle=False)
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------
# durable file operations


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _append_line(fd: int, data: bytes) -> None:
    """Append all of ``data`` to the open file descriptor and fsync it (os.write may write partially)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]
    os.fsync(fd)


def _write_json_atomic(path: Path, obj: Mapping[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        _write_file(tmp, (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


# ---------------------------------------------------------------------------------------------
# meta to JSON


class _NotJSON(TypeError):
    """The value has no faithful JSON form."""


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON (non-finite floats become None, small arrays lists), or raise _NotJSON."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) for k in value):
            raise _NotJSON("a mapping with non-string keys")
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray) and value.size <= _SMALL_ARRAY and value.dtype.kind in "biuf":
        return jsonable(value.tolist())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _dataclass_summary(value)
    raise _NotJSON(f"{type(value).__name__} has no JSON form")


def _dataclass_summary(obj: Any) -> dict[str, Any]:
    """The JSON-able fields of a dataclass (e.g. sim.Truth without its depth image), tagged with its type."""
    out: dict[str, Any] = {"_type": type(obj).__name__}
    for f in dataclasses.fields(obj):
        try:
            out[f.name] = jsonable(getattr(obj, f.name))
        except _NotJSON:
            continue
    return out


def _camera_json(camera: PinholeCamera) -> dict[str, Any]:
    return {k: jsonable(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy", "width", "height")}


def _calib_json(frame: Frame) -> dict[str, Any]:
    return {"camera": _camera_json(frame.camera), "baseline_m": float(frame.baseline_m), "doffs": float(frame.doffs)}


def _info_json(info: SourceInfo) -> dict[str, Any]:
    out = {k: jsonable(getattr(info, k)) for k in ("kind", "name", "serial", "width", "height", "fps", "state")}
    extra = {}
    for k, v in dict(info.extra).items():
        try:
            extra[str(k)] = jsonable(v)
        except _NotJSON:
            continue
    out["extra"] = extra
    return out


# ---------------------------------------------------------------------------------------------
