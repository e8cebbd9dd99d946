"""Pixels along the clicked segment and their 3D points (docs/method.md step 1, Eq. 2).

Units: pixel coordinates (x right, y down) of the colour image; disparity in pixels;
3D points in metres in the camera frame (X right, Y down, Z forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.types import Frame, MeasureError


def check_point(frame: Frame, p: object, name: str) -> tuple[float, float]:
    """``p`` as a finite (x, y) inside the image, or :class:`MeasureError` saying what to change."""
    try:
        arr = np.asarray(p, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeasureError(f"{name} must be a pair of pixel coordinates (x, y), got {p!r}") from exc
    if arr.shape != (2,):
        raise MeasureError(f"{name} must be a pair of pixel coordinates (x, y), got {p!r}")
    x, y = float(arr[0]), float(arr[1])
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MeasureError(f"{name}={p!r} is not finite; click inside the image")
    h, w = frame.disparity.shape
    if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
        raise MeasureError(
            f"{name}=({x:g}, {y:g}) is outside the {w}x{h} image; pick a point with 0<=x<={w - 1}, 0<=y<={h - 1}"
        )
    return x, y


def segment_pixels(x1: float, y1: float, x2: float, y2: float) -> np.ndarray:
    """Integer pixels from (x1, y1) to (x2, y2): one per column if |dx| > |dy|, else one per row.

    docs/method.md step 1. The major coordinate steps by one pixel from round(start) to round(end);
    the other is the segment's value there, rounded. Returns N x 2 int64 (x, y).
    """
    dx, dy = x2 - x1, y2 - y1
    along_x = abs(dx) > abs(dy)
    a0, a1 = (x1, x2) if along_x else (y1, y2)
    lo, hi = int(round(a0)), int(round(a1))
    major = np.arange(lo, hi + (1 if hi >= lo else -1), 1 if hi >= lo else -1, dtype=np.float64)
    if along_x:
        minor = y1 + (major - x1) * (dy / dx)
        xs, ys = major, np.rint(minor)
    else:
        minor = x1 + (major - y1) * (dx / dy) if dy != 0 else np.full_like(major, x1)
        xs, ys = np.rint(minor), major
    out = np.empty((major.size, 2), np.int64)
    out[:, 0], out[:, 1] = xs, ys
    return out


def extension_pixels(frame: Frame, start: tuple[float, float], away_from: tuple[float, float], length: int) -> np.ndarray:
    """Pixels of the ``length``-pixel extension beyond ``start``, pointing away from ``away_from``
    (docs/method.md step 6), excluding ``start`` itself and clipped to the image. N x 2 int64."""
    x0, y0 = start
    h, w = frame.disparity.shape
    # Beyond the image diagonal every pixel would be clipped: don't enumerate them.
    length = min(length, int(math.hypot(w, h)) + 2)
    ux, uy = x0 - away_from[0], y0 - away_from[1]
    norm = math.hypot(ux, uy)
    ux, uy = ux / norm, uy / norm
    px = segment_pixels(x0 + ux, y0 + uy, x0 + ux * length, y0 + uy * length)
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    return px[inside]


def backproject(frame: Frame, x: np.ndarray, y: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """3D points (m) of pixels (x, y) with disparity d (px): Eq. 2 with Z = fx B / (d + doffs)."""
    z = depth_of(frame, disparity)
    return backproject_depth(frame, x, y, z)


def depth_of(frame: Frame, disparity: np.ndarray) -> np.ndarray:
    """Depth (m) of disparity (px): Z = fx B / (d + doffs)."""
    return frame.camera.fx * frame.baseline_m / (np.asarray(disparity, dtype=np.float64) + frame.doffs)


def backproject_depth(frame: Frame, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Eq. 2: P = ((x - cx) Z / fx, (y - cy) Z / fy, Z), metres."""
    cam = frame.camera
    z = np.asarray(z, dtype=np.float64)
    return np.stack([(np.asarray(x) - cam.cx) * z / cam.fx, (np.asarray(y) - cam.cy) * z / cam.fy, z], axis=-1)


def ray(frame: Frame, x: float, y: float) -> np.ndarray:
    """Direction of pixel (x, y)'s viewing ray through the camera centre, scaled so that Z = 1."""
    cam = frame.camera
    return np.array([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0])


def valid_disparity(frame: Frame, d: np.ndarray) -> np.ndarray:
    """Samples with a disparity (px) a camera can produce (:meth:`Frame.valid`); others are holes."""
    return frame.valid(d)


def window_disparities(frame: Frame, x: float, y: float, window: int) -> np.ndarray:
    """The valid disparities (px) of the window x window box centred on pixel (x, y)."""
    h, w = frame.disparity.shape
    r = window // 2
    xi, yi = int(round(x)), int(round(y))
    patch = frame.disparity[max(0, yi - r) : min(h, yi + r + 1), max(0, xi - r) : min(w, xi + r + 1)]
    return patch[valid_disparity(frame, patch)]


def window_median_disparity(frame: Frame, x: float, y: float, window: int) -> float:
    """Median of the valid disparities (px) in a window x window box centred on pixel (x, y); NaN if none."""
    valid = window_disparities(frame, x, y, window)
    return float(np.median(valid)) if valid.size else math.nan


@dataclass(frozen=True)
class SegmentSamples:
    """The segment's pixels (all N) and the valid ones with their disparity and 3D points."""

    n_samples: int
    pixels: np.ndarray  # n_valid x 2 int64
    disparity: np.ndarray  # n_valid, px
    points: np.ndarray  # n_valid x 3, metres (Eq. 2)
    confidence: np.ndarray | None  # n_valid, when the frame has a confidence map


def sample_segment(frame: Frame, p1: tuple[float, float], p2: tuple[float, float]) -> SegmentSamples:
    """docs/method.md step 1: pixels on p1 -> p2, drop those without range, back-project the rest."""
    px = segment_pixels(p1[0], p1[1], p2[0], p2[1])
    d = frame.disparity[px[:, 1], px[:, 0]]
    ok = valid_disparity(frame, d)
    px, d = px[ok], d[ok].astype(np.float64)
    conf = None if frame.confidence is None else frame.confidence[px[:, 1], px[:, 0]].astype(np.float64)
    return SegmentSamples(len(ok), px, d, backproject(frame, px[:, 0], px[:, 1], d), conf)
