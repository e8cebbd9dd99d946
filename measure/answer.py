"""The :class:`Measurement` a method's end points become: distance, interval, verdict (metres, pixels).

``measurement`` builds it from two 3D end points (m) and a one-sigma (m); ``window_measurement``
from the click windows' ends (``measure.basic``). Both check the range (a finite distance, a finite
positive sigma), take the 95 % interval (``measure.uncertainty.interval``) and the verdict
(``measure.verdict.judge``).
"""

from __future__ import annotations

import math
import time

from typing import TYPE_CHECKING

import numpy as np

from measure.request import BEYOND_RANGE
from measure.sampling import SegmentSamples
from measure.types import MeasureError, Measurement
from measure.uncertainty import calibrated_sigma, interval
from measure.verdict import judge

if TYPE_CHECKING:
    from measure.basic import BasicEnds

BASIC_CLICK_SHARE = 1.5  # px: the basic answer's click error, as a share of the segment's pixel length


def check_range(dist: float, sigma: float) -> None:
    """Every answer has a finite distance and a finite, positive sigma (m)."""
    if not (math.isfinite(dist) and math.isfinite(sigma) and sigma > 0):
        raise MeasureError(BEYOND_RANGE)


def measurement(q1, q2, method, fit, basic: BasicEnds, sigma, samples, support, gap, warnings, t0, reasons=()) -> Measurement:
    """The answer between end points ``q1``, ``q2`` (m) with one-sigma ``sigma`` (m; calibrated here
    unless ``method`` is "robust", which calibrates its own terms)."""
    dist = float(np.linalg.norm(q2 - q1))
    sigma = calibrated_sigma(float(sigma), dist) if method != "robust" else float(sigma)
    check_range(dist, sigma)
    lo, hi = interval(dist, sigma)
    quality, why = judge(list(reasons), len(samples.points), dist, 0.5 * (hi - lo))
    return Measurement(
        distance_m=dist,
        method=method,
        fit=fit,
        p1_m=tuple(float(v) for v in q1),
        p2_m=tuple(float(v) for v in q2),
        basic_distance_m=basic.distance_m,
        uncertainty_m=float(sigma),
        n_samples=samples.n_samples,
        n_valid=len(samples.points),
        n_support=int(support.sum()),
        samples_px=samples.pixels,
        support=support,
        gap_detected=gap,
        warnings=tuple(warnings),
        elapsed_ms=(time.perf_counter() - t0) * 1e3,
        interval_m=(lo, hi),
        quality=quality,
        reasons=why,
    )


def window_measurement(
    basic: BasicEnds,
    method: str,
    t0: float,
    samples: SegmentSamples | None = None,
    warnings: tuple[str, ...] = (),
    gap: bool = False,
    support: np.ndarray | None = None,
    reasons: list[str] | tuple[str, ...] = (),
    window_sigma: float | None = None,
) -> Measurement:
    """The answer between the click windows' end points (the basic answer, and the fallback of the
    other methods), credited to ``method``; ``window_sigma`` (m) replaces the windows' own sigma."""
    if samples is None:  # the basic method samples only the two clicks
        pixels = np.array([basic.click1, basic.click2], dtype=np.float64)
        n_samples = 2
        support = np.ones(2, bool)
    else:
        pixels, n_samples = samples.pixels, samples.n_samples
    sup = np.zeros(len(pixels), bool) if support is None else support
    dist = basic.distance_m
    # The window medians' standard errors leave out the click and edge effects the robust answer models.
    base = basic.uncertainty_m if window_sigma is None else window_sigma
    sigma = calibrated_sigma(math.hypot(base, BASIC_CLICK_SHARE * dist * 2.0 / max(1.0, math.dist(basic.click1, basic.click2))), dist)
    check_range(dist, sigma)
    lo, hi = interval(dist, sigma)
    why = list(reasons) + (["gap detected"] if gap and "gap detected" not in reasons else [])
    quality, why = judge(why, None if samples is None else len(samples.points), dist, 0.5 * (hi - lo))
    return Measurement(
        distance_m=basic.distance_m,
        method=method,
        fit="none",
        p1_m=tuple(float(v) for v in basic.p1_m),
        p2_m=tuple(float(v) for v in basic.p2_m),
        basic_distance_m=basic.distance_m,
        uncertainty_m=sigma,
        n_samples=n_samples,
        n_valid=len(pixels),
        n_support=int(sup.sum()),
        samples_px=pixels,
        support=sup,
        gap_detected=gap,
        warnings=warnings,
        elapsed_ms=(time.perf_counter() - t0) * 1e3,
        interval_m=(lo, hi),
        quality=quality,
        reasons=why,
    )
