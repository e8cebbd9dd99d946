"""Length of a polyline of clicks (m): each leg measured as a segment, the legs' errors combined.

The value is the sum of the legs' ``measure_distance`` answers. Legs that share a click share that
end's error: moving the shared end by e changes one leg by u_k . e and the next by -u_k+1 . e (u the
legs' unit directions), so their covariance is -s_k s_k+1 cos(theta) with theta the turn between
them and s² = sigma² / 2 each end's share of a leg's variance (Eq. 14):
sigma² = sum_k sigma_k² - sum_k sigma_k sigma_k+1 cos(theta_k). A straight path's inner ends cancel;
a path that doubles back counts them twice.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from measure.distance import measure_distance
from measure.shape_types import ShapeMeasurement
from measure.support import check_options, check_points, verdict
from measure.types import Frame, MeasureOptions, Measurement


def path_sigma(legs: Sequence[Measurement]) -> float:
    """Eq. 14: one-sigma (m) of the sum of ``legs`` whose consecutive ones share an end."""
    s = np.array([m.uncertainty_m for m in legs])
    var = float((s**2).sum())
    for a, b in zip(legs, legs[1:]):
        u = np.subtract(a.p2_m, a.p1_m)
        v = np.subtract(b.p2_m, b.p1_m)
        cos = float(u @ v / (np.linalg.norm(u) * np.linalg.norm(v))) if np.linalg.norm(u) * np.linalg.norm(v) > 0 else 0.0
        var -= a.uncertainty_m * b.uncertainty_m * cos
    return math.sqrt(max(var, 0.0))


def measure_path(frame: Frame, points: Sequence[tuple[float, float]], options: MeasureOptions | None = None) -> ShapeMeasurement:
    """Length (m) of the polyline through the clicked ``points`` (x, y px), at least two.

    Raises:
        MeasureError: fewer than two clicks, or any leg that ``measure_distance`` refuses (the message
            names the leg).
    """
    t0 = time.perf_counter()
    opts = check_options(options)
    pts = check_points(frame, points, 2, "a path")
    legs = []
    for k in range(len(pts) - 1):
        try:
            legs.append(measure_distance(frame, tuple(pts[k]), tuple(pts[k + 1]), opts))
        except ValueError as err:
            raise type(err)(f"leg {k + 1} (point {k + 1} to {k + 2}): {err}") from None
    value = float(sum(m.distance_m for m in legs))
    sigma = path_sigma(legs)
    reasons = [f"leg {k + 1}: {r}" for k, m in enumerate(legs) for r in m.reasons]
    worst = max(legs, key=lambda m: ("good", "check", "unreliable").index(m.quality)).quality
    quality, why, interval = verdict(value, sigma, reasons, unreliable=worst == "unreliable")
    if quality == "good" and worst == "check":
        quality = "check"
    vertices = (legs[0].p1_m, *(m.p2_m for m in legs))
    return ShapeMeasurement("path", value, "m", sigma, interval, quality, why, tuple(map(tuple, pts)),
                            tuple(tuple(map(float, v)) for v in vertices), tuple(m.distance_m for m in legs),
                            tuple(m.uncertainty_m for m in legs), (time.perf_counter() - t0) * 1000.0)
