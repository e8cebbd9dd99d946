"""Images the service sends: PNG (exact pixels) and JPEG (the live view: cheaper to encode and
smaller, docs/decisions/service-speed.md) encoding, the colour-mapped disparity view, the grey
confidence view, thumbnails, and the JSON view of a ring frame."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np


from service.frames import RingFrame
from service.provenance import recorded_index, recording_name

THUMB_WIDTH = 240
LIVE_JPEG_QUALITY = 85
THUMB_JPEG_QUALITY = 80


def encode_png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def disparity_range(disparity: np.ndarray) -> tuple[float, float] | None:
    """The disparity (px) mapped to the ends of the colour map: its 1st and 99th percentile."""
    valid = np.isfinite(disparity)
    if not valid.any():
        return None
    lo, hi = np.percentile(disparity[valid], [1, 99])
    return float(lo), float(hi)


def turbo_colors(n: int = 16) -> list[str]:
    """``n`` evenly spaced colours of the turbo map as ``#rrggbb``, low disparity (far) first."""
    ramp = cv2.applyColorMap(np.linspace(0, 255, n).astype(np.uint8).reshape(-1, 1), cv2.COLORMAP_TURBO)
    return [f"#{r:02x}{g:02x}{b:02x}" for b, g, r in ramp.reshape(-1, 3).tolist()]
def encode_jpeg(image: np.ndarray, quality: int = LIVE_JPEG_QUALITY) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


LIVE_JPEG = "color.jpg"  # the ring's cache key of the live view's JPEG


def live_jpeg(entry: RingFrame) -> bytes:
    """The live view's JPEG of a ring frame, encoded once per frame."""
    return entry.encoded(LIVE_JPEG, lambda f: encode_jpeg(f.image), image_only=True)


def png_from_jpeg(data: bytes) -> bytes:
    """A small JPEG (a thumbnail) as PNG, for the URLs that promise PNG."""
    return encode_png(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR))


def colorize_disparity(disparity: np.ndarray) -> np.ndarray:
    """BGR image of a disparity map (px): turbo colour map over its 1st..99th percentile; no data is black."""
    valid = np.isfinite(disparity)
    out = np.zeros(disparity.shape + (3,), np.uint8)
    span = disparity_range(disparity)
    if span is None:
        return out
    lo, hi = span
    scale = 255.0 / max(hi - lo, 1e-6)
    norm = np.clip((np.where(valid, disparity, lo) - lo) * scale, 0, 255).astype(np.uint8)
    mapped = cv2.applyColorMap(norm, cv2.COLORMAP_TURBO)
    out[valid] = mapped[valid]
    return out


def confidence_image(confidence: np.ndarray) -> np.ndarray:
    """Grey uint8 image of a confidence map in [0, 1]: round(c * 255), so black = no support (0) and
    white = fully supported (1), the recordings' encoding; NaN is black."""
    return np.rint(np.clip(np.nan_to_num(confidence, nan=0.0), 0.0, 1.0) * 255.0).astype(np.uint8)


def quarter(image: np.ndarray) -> np.ndarray:
    """``image`` at 1/4 size by area averaging: what the saved JPEG's reduced decode gives, for a thumbnail."""
    return cv2.resize(image, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)


def make_thumb(image: np.ndarray, full_width: int, lines: list[tuple[list[list[float]], bool]]) -> bytes:
    """A small JPEG of a frame's colour ``image`` (full size, or a reduced decode of a frame
    ``full_width`` pixels wide) with the measurement drawn on it: ``lines`` are polylines (points in
    full-size pixels, closed or not; a segment is one line of its two clicks, whose ends get dots);
    bilinear resize + JPEG."""
    h, w = image.shape[:2]
    s = THUMB_WIDTH / full_width
    small = cv2.resize(image, (THUMB_WIDTH, max(1, round(h * THUMB_WIDTH / w))), interpolation=cv2.INTER_LINEAR)
    scaled = [(np.round((np.asarray(pts, float).reshape(-1, 2) + 0.5) * s * 16).astype(np.int32), closed) for pts, closed in lines]
    scaled = [(pts, closed) for pts, closed in scaled if len(pts)]
    for colour, width in (((0, 0, 0), 4), ((40, 220, 255), 2)):  # a dark rim under the line, for any background
        cv2.polylines(small, [pts for pts, closed in scaled if not closed], False, colour, width, cv2.LINE_AA, shift=4)
        cv2.polylines(small, [pts for pts, closed in scaled if closed], True, colour, width, cv2.LINE_AA, shift=4)
    if len(scaled) == 1 and len(scaled[0][0]) == 2:
        for p in scaled[0][0]:
            cv2.circle(small, tuple(int(v) for v in p), 4 * 16, (40, 220, 255), -1, cv2.LINE_AA, shift=4)
    return encode_jpeg(small, THUMB_JPEG_QUALITY)


def truth_json(truth: Any) -> dict[str, Any] | None:
    """The simulator's ground truth (a Truth object, or the JSON summary a recording keeps)."""
    if truth is None:
        return None
    keys = ("p1_px", "p2_px", "p1_m", "p2_m", "length_m", "target", "is_gap")
    get = truth.get if isinstance(truth, dict) else (lambda k: getattr(truth, k, None))
    out: dict[str, Any] = {}
    for k in keys:
        v = get(k)
        if isinstance(v, (tuple, list, np.ndarray)):
            v = [float(x) for x in np.asarray(v, dtype=float).ravel()]
        elif isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        out[k] = v
    return out


def frame_json(entry: RingFrame) -> dict[str, Any]:
    f = entry.packed  # its numbers and meta, nothing unpacked
    h, w = f.shape
    meta = {k: v for k, v in dict(f.meta).items() if isinstance(v, (str, int, float, bool)) and k != "truth"}
    return {
        "id": entry.id,
        "uid": entry.uid,
        "width": w,
        "height": h,
        "timestamp": float(f.timestamp),
        "received": entry.received,
        "frozen": entry.frozen,
        "source": str(f.meta.get("source", "")),
        "meta": {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in meta.items()},
        "truth": truth_json(f.meta.get("truth")),
        "has_confidence": f.confidence is not None,
        "replay_index": recorded_index(f),
        "recording": recording_name(f),
    }
