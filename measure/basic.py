"""The paper's "Basic" baseline (``method="basic"``): window-median disparity at each click, Eq. 2, |P1 - P2|.

``basic_ends`` gives the click windows' end points (m) that every method reads (the basic answer,
the paper's end point input, the robust method's fallback and checks); ``measure_basic`` is the
method: both windows need depth, the answer is their distance (docs/method.md "Problem").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.answer import window_measurement
from measure.edges import on_edge
from measure.request import NO_DEPTH, Request, require_resolved_windows
from measure.robust_range import median
from measure.sampling import backproject, window_disparities
from measure.types import Frame, MeasureError, Measurement
from measure.uncertainty import depth_sigma, disparity_quantum, endpoint_depth_sigma, window_disparity_se


@dataclass(frozen=True)
class BasicEnds:
    """End points (m; NaN where the window has no valid disparity) and their distance."""

    p1_m: np.ndarray
    p2_m: np.ndarray
    distance_m: float
    uncertainty_m: float
    z_sigma: tuple[float, float]  # standard error (m) of each end point's depth
    click1: tuple[float, float]
    click2: tuple[float, float]
    disparity: tuple[float, float]  # each window's median disparity (px, without doffs; NaN: no valid pixel)
    disparity_se: tuple[float, float]  # its standard error (px)

    @property
    def ok(self) -> bool:
        return math.isfinite(self.distance_m)


def basic_ends(frame: Frame, xy1: tuple[float, float], xy2: tuple[float, float], window: int) -> BasicEnds:
    """Median of the valid disparities in a ``window`` x ``window`` box at each click, Eq. 2."""
    w1 = window_disparities(frame, xy1[0], xy1[1], window)
    w2 = window_disparities(frame, xy2[0], xy2[1], window)
    d = np.array([median(w1) if w1.size else np.nan, median(w2) if w2.size else np.nan])
    pts = backproject(frame, np.array([xy1[0], xy2[0]]), np.array([xy1[1], xy2[1]]), d)
    dist = float(np.linalg.norm(pts[0] - pts[1]))
    q = disparity_quantum(np.concatenate([w1, w2]))
    fb = frame.camera.fx * frame.baseline_m
    se = (window_disparity_se(w1, q), window_disparity_se(w2, q))
    s1, s2 = (depth_sigma(float(pts[e, 2]), fb, se[e]) for e in (0, 1))
    if dist > 0 and math.isfinite(dist):
        sigma = endpoint_depth_sigma(pts[0], pts[1], s1, s2)
    elif dist == 0:
        # Both clicks on one viewing ray r (one pixel, to float precision): D = |r| |Z1 - Z2|.
        sigma = float(np.linalg.norm(pts[0] / pts[0][2])) * math.hypot(s1, s2)
    else:
        sigma = math.nan
    return BasicEnds(pts[0], pts[1], dist, sigma, (s1, s2), xy1, xy2, (float(d[0]), float(d[1])), se)


def measure_basic(request: Request) -> Measurement:
    """The basic answer: the distance (m) between the click windows' end points; MeasureError when a
    window has no depth or its depth is unbounded within its error."""
    require_resolved_windows(request)
    basic, frame, xy1, xy2 = request.basic, request.frame, request.xy1, request.xy2
    if not basic.ok:
        raise MeasureError(f"{NO_DEPTH}: the basic method needs depth at both clicks; click on a surface with depth or use method='robust'")
    edge = any(on_edge(frame, a, b, d) for a, b, d in ((xy1, xy2, basic.disparity[0]), (xy2, xy1, basic.disparity[1])))
    return window_measurement(basic, "basic", request.t0, reasons=["end point on a depth edge"] if edge else [])
