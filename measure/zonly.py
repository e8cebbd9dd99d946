"""The paper's ablation "robust fit of Z alone" (docs/method.md "Results to beat").

Inputs as :func:`measure.measure_distance`. Steps: the depth Z (m) of the valid samples is fit
robustly as a straight line Z(t) of the pixel position t (px) along the segment, by FAST-MCD
(p = 2) on (t, Z): an exact fit (at least h samples on one quantized depth, or on one line) is
taken as the model, as the paper does, and its first principal component otherwise. The end points
are the clicked pixels with depth Z(0) and Z(|p2 - p1|), back-projected by Eq. 2. Gap detection as
in the paper (step 6). The paper does not say how the end points are rebuilt from the fitted depth;
the readings measured are in docs/decisions/z-only-reading.md.
"""

from __future__ import annotations

import math
import time

import numpy as np

from measure.basic import basic_ends
from measure.request import MIN_FIT_SAMPLES, NO_DEPTH, validate_request
from measure.dline import mcd_line
from measure.gap import extension_depth, is_gap
from measure.mcd import fast_mcd
from measure.sampling import backproject_depth, sample_segment
from measure.types import Frame, MeasureError, MeasureOptions, Measurement
from measure.uncertainty import disparity_quantum, endpoint_depth_sigma


def measure_z_only(
    frame: Frame,
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
) -> Measurement:
    """Distance (m) from a robust line Z(t) of depth along the segment (the paper's ablation)."""
    t0 = time.perf_counter()
    xy1, xy2 = validate_request(frame, p1, p2, options)
    basic = basic_ends(frame, xy1, xy2, options.window)
    samples = sample_segment(frame, xy1, xy2)
    n = len(samples.points)
    if n < MIN_FIT_SAMPLES:
        raise MeasureError(f"only {n} valid samples along the segment; Z-only needs {MIN_FIT_SAMPLES}; measure where the depth map has data")
    dx, dy = xy2[0] - xy1[0], xy2[1] - xy1[1]
    length = math.hypot(dx, dy)
    t = (samples.pixels - np.array(xy1)) @ np.array([dx / length, dy / length])
    z = samples.points[:, 2]
    res = fast_mcd(np.c_[t, z], support_fraction=options.support_fraction, seed=options.seed)
    line = mcd_line(res)
    icpt, slope = line if line is not None else (float(res.location[1]), 0.0)
    z_end = np.array([icpt, icpt + slope * length])
    if not (z_end > 0).all():
        raise MeasureError("the robust depth line runs behind the camera at an end point; click elsewhere")
    ends = backproject_depth(frame, np.array([xy1[0], xy2[0]]), np.array([xy1[1], xy2[1]]), z_end)
    q1, q2 = ends[0], ends[1]
    sup = res.support
    resid = z[sup] - (icpt + slope * t[sup])
    s_z = float(np.sqrt((resid**2).mean())) if sup.sum() > 2 else 0.0
    tc = t[sup] - t[sup].mean()
    sxx = float((tc**2).sum()) or math.inf
    se = [s_z * math.sqrt(1.0 / max(1, sup.sum()) + (tt - t[sup].mean()) ** 2 / sxx) for tt in (0.0, length)]
    # No residual (one quantized level, an exact fit) is no certainty: at least one disparity
    # quantum's rounding, Z² / (fB) * q / sqrt(12), at each end.
    fb = frame.camera.fx * frame.baseline_m
    q = disparity_quantum(samples.disparity)
    se = [max(s, float(zz) ** 2 / fb * q / math.sqrt(12.0)) for s, zz in zip(se, z_end)]
    sigma = endpoint_depth_sigma(q1, q2, se[0], se[1])
    gap = False
    warnings: tuple[str, ...] = () if basic.ok else (NO_DEPTH,)
    if options.gap_detection:
        ext = (extension_depth(frame, xy1, xy2, options.extension_px), extension_depth(frame, xy2, xy1, options.extension_px))
        gap = is_gap(ext, (float(z_end[0]), float(z_end[1])))
        if gap and basic.ok:
            q1, q2, sigma = basic.p1_m, basic.p2_m, basic.uncertainty_m
            warnings += ("gap detected: both extensions are in front of the end points; basic answer",)
    return Measurement(
        distance_m=float(np.linalg.norm(q2 - q1)),
        method="z-only",
        fit="none" if gap else ("constant-depth" if slope == 0.0 else "line"),
        p1_m=tuple(float(v) for v in q1),
        p2_m=tuple(float(v) for v in q2),
        basic_distance_m=basic.distance_m,
        uncertainty_m=float(sigma),
        n_samples=samples.n_samples,
        n_valid=n,
        n_support=int(sup.sum()),
        samples_px=samples.pixels,
        support=sup,
        gap_detected=gap,
        warnings=warnings,
        elapsed_ms=(time.perf_counter() - t0) * 1e3,
    )
