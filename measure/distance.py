"""Point-to-point measurement entry point (METHOD.md). Foundation version: "basic" only.

The robust and paper methods land with issue 3.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .types import Frame, MeasureError, MeasureOptions, Measurement


def _check_point(frame: Frame, p: tuple[float, float], name: str) -> tuple[float, float]:
    try:
        x, y = float(p[0]), float(p[1])
    except (TypeError, ValueError, IndexError) as exc:
        raise MeasureError(f"{name} must be a pair of pixel coordinates (x, y), got {p!r}") from exc
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MeasureError(f"{name}={p!r} is not finite; click inside the image")
    h, w = frame.disparity.shape
    if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
        raise MeasureError(f"{name}=({x:g}, {y:g}) is outside the {w}x{h} image; pick a point with 0<=x<={w - 1}, 0<=y<={h - 1}")
    return x, y


def window_median_disparity(frame: Frame, x: float, y: float, window: int) -> float:
    """Median of the valid disparities (px) in a window x window box centred on pixel (x, y); NaN if none."""
    h, w = frame.disparity.shape
    r = window // 2
    xi, yi = int(round(x)), int(round(y))
    patch = frame.disparity[max(0, yi - r) : min(h, yi + r + 1), max(0, xi - r) : min(w, xi + r + 1)]
    valid = patch[np.isfinite(patch) & (patch + frame.doffs > 0)]
    return float(np.median(valid)) if valid.size else math.nan


def backproject(frame: Frame, x: np.ndarray, y: np.ndarray, disparity: np.ndarray) -> np.ndarray:
    """3D points (m) of pixels (x, y) with disparity d (px): Eq. 2 with Z = fx B / (d + doffs)."""
    cam = frame.camera
    z = cam.fx * frame.baseline_m / (np.asarray(disparity, dtype=np.float64) + frame.doffs)
    return np.stack([(np.asarray(x) - cam.cx) * z / cam.fx, (np.asarray(y) - cam.cy) * z / cam.fy, z], axis=-1)


def measure_distance(
    frame: Frame,
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
) -> Measurement:
    t0 = time.perf_counter()
    x1, y1 = _check_point(frame, p1, "p1")
    x2, y2 = _check_point(frame, p2, "p2")
    if (x1, y1) == (x2, y2):
        raise MeasureError("p1 and p2 are the same pixel; click two different points")
    d1 = window_median_disparity(frame, x1, y1, options.window)
    d2 = window_median_disparity(frame, x2, y2, options.window)
    if not (math.isfinite(d1) and math.isfinite(d2)):
        raise MeasureError("an end point has no valid disparity within the window; click on a surface with depth")
    pts = backproject(frame, np.array([x1, x2]), np.array([y1, y2]), np.array([d1, d2]))
    dist = float(np.linalg.norm(pts[0] - pts[1]))
    return Measurement(
        distance_m=dist,
        method="basic",
        fit="none",
        p1_m=tuple(map(float, pts[0])),
        p2_m=tuple(map(float, pts[1])),
        basic_distance_m=dist,
        uncertainty_m=math.nan,
        n_samples=2,
        n_valid=2,
        n_support=2,
        samples_px=np.array([[x1, y1], [x2, y2]]),
        support=np.ones(2, bool),
        gap_detected=False,
        warnings=(),
        elapsed_ms=(time.perf_counter() - t0) * 1e3,
    )
