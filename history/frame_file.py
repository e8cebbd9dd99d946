"""One measured frame as one compact file: what reopening and re-measuring it needs, and no more.

A ``.frame`` file is an uncompressed zip of
- ``disparity.png``: 16-bit PNG, code = round(d * 64), 0 = invalid (``device.formats.recording``'s
  encoding; exact to the 1/64 px step, within 1/128 px otherwise); ``disparity.npy`` (float32,
  lossless) instead for disparity of 1024 px or more, which 16 bits cannot hold;
- ``color.jpg``: JPEG quality 92; a measurement that reads the colour image (a box's sides) is made on
  the image as this file holds it (:func:`as_stored`), so re-measuring the file gives its answer;
- ``confidence.png``: optional, 8-bit;
- ``frame.json``: camera, baseline, doffs, timestamp and the frame's JSON-able meta.
Its size against the earlier ``.npz`` is in docs/decisions/frame-file.md.
:func:`write_durably` makes it crash-safe: temp file, fsync, rename, fsync of the folder.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from device.formats.recording import DISPARITY_SCALE, MAX_DISPARITY_CODE, decode_confidence, decode_disparity, encode_confidence
from measure import Frame, PinholeCamera

SUFFIX = ".frame"
TMP_SUFFIX = ".tmp"
JPEG_QUALITY = 92


def _json_meta(meta: Any) -> dict[str, Any]:
    """The JSON-serialisable scalar part of a frame's meta (e.g. not the simulator's Truth object)."""
    return {str(k): v for k, v in dict(meta or {}).items() if isinstance(v, (str, int, float, bool)) or v is None}


# Row filter "up" and zlib's run-length strategy: faster than OpenCV's defaults on disparity and
# confidence maps (smooth, with runs of invalid pixels) for a few more bytes; still lossless
# (docs/decisions/frame-file.md).
_PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):  # OpenCV >= 4.10
    _PNG_FAST += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP]


def _png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image, _PNG_FAST)
    if not ok:
        raise ValueError(f"PNG encoding of a {image.shape} {image.dtype} image failed")
    return buf.tobytes()


def disparity_code(disparity: np.ndarray) -> np.ndarray | None:
    """``device.formats.recording``'s 16-bit code of a disparity map (round(d * 64), 0 = invalid: NaN,
    negative or below 1/128 px), in float32 (faster than its float64 encoder); None when a
    disparity of 1024 px or more does not fit."""
    scaled = np.asarray(disparity, np.float32) * np.float32(DISPARITY_SCALE)
    np.rint(scaled, out=scaled)
    np.nan_to_num(scaled, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
    if scaled.max(initial=0.0) > MAX_DISPARITY_CODE:
        return None
    np.maximum(scaled, 0.0, out=scaled)
    return scaled.astype(np.uint16)


def _jpeg(image: np.ndarray) -> bytes:
    ok, jpg = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError(f"JPEG encoding of a {image.shape} image failed")
    return jpg.tobytes()


def as_stored(frame: Frame) -> Frame:
    """``frame`` with its colour image as its ``.frame`` file will hold it (the JPEG decoded): what a
    measurement that reads the image is made on, so that the stored frame re-measures to its answer."""
    image = cv2.imdecode(np.frombuffer(_jpeg(frame.image), np.uint8), cv2.IMREAD_COLOR)
    return dataclasses.replace(frame, image=image)


def encode_frame(frame: Frame) -> bytes:
    """The ``.frame`` bytes of ``frame`` (see the module docstring)."""
    cam = frame.camera
    members: dict[str, bytes] = {}
    code = disparity_code(frame.disparity)
    if code is not None:
        members["disparity.png"] = _png(code)
    else:
        buf = io.BytesIO()
        np.save(buf, np.asarray(frame.disparity, np.float32), allow_pickle=False)
        members["disparity.npy"] = buf.getvalue()
    members["color.jpg"] = _jpeg(frame.image)
    if frame.confidence is not None:
        members["confidence.png"] = _png(encode_confidence(frame.confidence))
    info = {
        "camera": {k: getattr(cam, k) for k in ("fx", "fy", "cx", "cy", "width", "height")},
        "baseline_m": float(frame.baseline_m),
        "doffs": float(frame.doffs),
        "timestamp": float(frame.timestamp),
        "meta": _json_meta(frame.meta),
    }
    members["frame.json"] = json.dumps(info).encode()
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:  # the members are compressed already
        for name, data in members.items():
            zf.writestr(name, data)
    return out.getvalue()


def decode_frame(data: bytes) -> Frame:
    """The frame in ``.frame`` bytes; raises ValueError / KeyError / zipfile.BadZipFile when damaged."""
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        names = set(zf.namelist())
        info = json.loads(zf.read("frame.json"))
        if "disparity.png" in names:
            disparity = decode_disparity(_image(zf.read("disparity.png"), np.uint16))
        else:
            disparity = np.load(io.BytesIO(zf.read("disparity.npy")), allow_pickle=False)
        image = _image(zf.read("color.jpg"), np.uint8, cv2.IMREAD_COLOR)
        confidence = decode_confidence(_image(zf.read("confidence.png"), np.uint8)) if "confidence.png" in names else None
    cam = info["camera"]
    return Frame(
        image=image,
        disparity=disparity,
        camera=PinholeCamera(fx=cam["fx"], fy=cam["fy"], cx=cam["cx"], cy=cam["cy"], width=int(cam["width"]), height=int(cam["height"])),
        baseline_m=info["baseline_m"],
        doffs=info["doffs"],
        confidence=confidence,
        timestamp=info["timestamp"],
        meta=info["meta"],
    )


def load_frame_file(path: Path) -> Frame:
    """A saved frame from ``path``: a ``.frame`` file, or the ``.npz`` that history stores kept before.
    Raises OSError when unreadable and ValueError / KeyError / TypeError / zipfile.BadZipFile when damaged."""
    if path.suffix.lower() == ".npz":
        return _load_npz(path)
    return decode_frame(path.read_bytes())


def _load_npz(path: Path) -> Frame:
    with np.load(path, allow_pickle=False) as z:
        fx, fy, cx, cy, w, h = z["camera"].tolist()
        baseline, doffs, ts = z["numbers"].tolist()
        return Frame(
            image=z["image"],
            disparity=z["disparity"],
            camera=PinholeCamera(fx=fx, fy=fy, cx=cx, cy=cy, width=int(w), height=int(h)),
            baseline_m=baseline,
            doffs=doffs,
            confidence=z["confidence"] if "confidence" in z.files else None,
            timestamp=ts,
            meta=json.loads(str(z["meta"])),
        )


def _image(data: bytes, dtype: type, flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if img is None or img.dtype != dtype:
        raise ValueError("an image inside the frame file cannot be decoded")
    return img


def write_durably(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that after any crash the file is either absent or complete:
    ``<path>.tmp``, fsync, rename, fsync of the folder (the rename itself must survive)."""
    tmp = path.with_name(path.name + TMP_SUFFIX)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
