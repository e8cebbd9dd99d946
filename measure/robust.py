"""The robust method (``method="robust"``, the default): a robust disparity line along the segment,
each end on its clicked pixel's viewing ray.

Steps (pixels in, metres out):

1. Sample the segment (docs/method.md step 1, ``measure.request.fit_samples``).
2. Fit disparity as a line along it, d(t) = alpha + beta t (``measure.dline``: FAST-MCD start, Tukey
   IRLS, a second start through the click windows), on few quantized levels the interval-censored
   line (``measure.censored``).
3. Choose each end's model (``measure.surfaces``): the line, a surface of its own along the segment,
   the click's clean window (``_clean_ends``), the plane beside the segment (``_neighbourhood_ends``,
   ``measure.neighbourhood``) or, for an extrapolated end, its click window (``_observed_ends``).
4. Back-project each end on its clicked pixel's ray at that depth (Eq. 2): no depth at the click is
   needed (warning "endpoint has no depth within window").
5. Gap detection on evidence at both ends (``measure.gap.clear_gap_ends``): on a gap, the clicks' rays
   at the ends' surfaces.
6. One-sigma from the fit, click, quantization, model-choice and structure terms, calibrated
   (``measure.uncertainty``); the 95 % interval and the verdict (``measure.verdict``). A line that
   says little (``IMPRECISE``) yields to clean click windows.

Why: the clicked pixel is exact and its depth the least reliable of all, and the disparity line puts
the noise where stereo has it (docs/decisions/viewing-ray-ends.md); each threshold's measurement is
on the decision page its helper names.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from measure.answer import measurement, window_measurement
from measure.basic import BasicEnds, basic_ends
from measure.bend import bent_end_models
from measure.censored import censored_line, few_levels
from measure.confidence import LOW_CONFIDENCE_REASON, low_confidence, support_inflation
from measure.dline import DisparityLine, fit_disparity_line
from measure.edges import on_edge, on_surface_edge
from measure.gap import GAP_SIGMA_SCALE, clear_gap_ends, leading_run
from measure.neighbourhood import end_plane
from measure.request import BEYOND_RANGE, MIN_FIT_SAMPLES, NO_DEPTH, Request, fit_samples, focal_baseline, resolved, validate_request
from measure.sampling import SegmentSamples, ray, sample_segment, valid_disparity
from measure.surfaces import CLEAN_SPREAD, DISAGREE_REL, LOCAL_ROUGHNESS, EndModels, clean_window_disparity, extrapolated, select_end_models
from measure.types import Frame, MeasureError, MeasureOptions, Measurement
from measure.uncertainty import (
    MODEL_SHARE,
    calibrated_sigma,
    click_sigma,
    correlation_inflation,
    disparity_quantum,
    distinct_levels,
    endpoint_depth_sigma,
    quantization_sigma,
)
from measure.verdict import EXTRAPOLATED_PX, FEW_SAMPLES, FEW_SHARE, disagreement

IMPRECISE = 0.08  # relative one-sigma above which the robust line yields to clean click windows
DECISION_CLICK_PX = 1.5  # px: the click error at which IMPRECISE is judged (a mouse's; calibrated with it)


def measure_robust(request: Request) -> Measurement:
    """The robust answer (m) for ``request`` (module docstring, steps 1-6); MeasureError when the
    segment has too few valid samples or an end's depth is unbounded."""
    return _robust(request, fit_samples(request))


def _click_term(frame: Frame, xy1, xy2, d_end: np.ndarray, slope: np.ndarray, dist: float, click_px: float) -> float:
    return click_sigma(lambda x, y: ray(frame, x, y), xy1, xy2, d_end, slope, focal_baseline(frame), frame.doffs, dist, click_px)


def robust_with_terms(frame: Frame, xy1, xy2, options: MeasureOptions, samples: SegmentSamples | None = None) -> tuple[Measurement, dict[str, float]]:
    """The robust answer on ``frame`` with the model-sigma terms it was built from (m, before
    ``calibrated_sigma``): "fit" (the line's, correlation-inflated, or a gap's extension depths), and
    "click", "quant", "model", "structure". ``samples`` replaces the segment's own (e.g. samples
    pooled from several frames of one viewpoint, ``measure.sequence``); the end windows, edges and
    gap extensions are read from ``frame``. The terms are empty for a window (basic) answer."""
    xy1, xy2 = validate_request(frame, xy1, xy2, options)
    samples = sample_segment(frame, xy1, xy2) if samples is None else samples
    if samples.n_samples < MIN_FIT_SAMPLES or len(samples.points) < MIN_FIT_SAMPLES:
        raise MeasureError(
            f"only {len(samples.points)} valid samples along the segment from p1 to p2 ({MIN_FIT_SAMPLES} needed); "
            "measure where the depth map has data, or use method='basic'"
        )
    terms: dict[str, float] = {}
    request = Request(frame, xy1, xy2, options, basic_ends(frame, xy1, xy2, options.window), time.perf_counter())
    return _robust(request, samples, terms), terms


def _robust(request: Request, samples: SegmentSamples, terms: dict[str, float] | None = None) -> Measurement:
    frame, xy1, xy2, options, basic, t0 = request.frame, request.xy1, request.xy2, request.options, request.basic, request.t0
    dx, dy = xy2[0] - xy1[0], xy2[1] - xy1[1]
    length = math.hypot(dx, dy)
    t = (samples.pixels - np.array(xy1)) @ np.array([dx / length, dy / length])
    quantum = disparity_quantum(samples.disparity)
    alt = None
    if basic.ok:
        # The line through the click windows' medians: a second start for the fit (measure.dline).
        alt = (basic.disparity[0], (basic.disparity[1] - basic.disparity[0]) / length)
    line = fit_disparity_line(t, samples.disparity, options.support_fraction, options.seed, quantum, alt_start=alt)
    line = _censored(t, samples.disparity, line, quantum)
    ends = select_end_models(t, samples.disparity, length, line, quantum, options.seed)
    ends = _clean_ends(frame, xy1, xy2, options.window, ends)
    ends = _neighbourhood_ends(frame, xy1, xy2, ends, quantum, max(line.sigma_d, quantum / math.sqrt(12.0)))
    ends = _observed_ends(frame, xy1, xy2, basic, t, line, length, ends, options.window)
    ends = bent_end_models(t, samples.disparity, length, quantum, line.sigma_d, ends)
    d_end = ends.d_end
    warnings: list[str] = []
    reasons: list[str] = []
    if not basic.ok:
        warnings.append(NO_DEPTH + " (measured where the click's viewing ray meets the robust line)")
    if not (d_end + frame.doffs > 0).all():
        if not basic.ok:
            raise MeasureError("the robust line runs to infinite depth at an end point that has no depth; click elsewhere")
        warnings.append("the robust line runs to infinite depth at an end point; basic answer")
        return window_measurement(basic, "robust", t0, samples, tuple(warnings), support=line.support, reasons=["end point extrapolated"])
    inflate = correlation_inflation(samples.disparity[line.support] - line.at(t[line.support]))
    floor = quantum / math.sqrt(12.0)
    if not all(resolved(float(d_end[e]) + frame.doffs, max(inflate * math.sqrt(max(0.0, float(ends.cov[e, e]))), floor)) for e in (0, 1)):
        raise MeasureError(BEYOND_RANGE)
    fb = focal_baseline(frame)
    r1, r2 = ray(frame, *xy1), ray(frame, *xy2)
    z = fb / (d_end + frame.doffs)
    q1, q2 = r1 * z[0], r2 * z[1]
    dist = float(np.linalg.norm(q2 - q1))
    # dD/dd_i = dD/dZ_i * dZ_i/dd_i with dZ/dd = -Z²/(fB); the two fitted disparities are correlated.
    grad = np.array([r1 @ (q1 - q2), r2 @ (q2 - q1)]) / dist * (-(z**2) / fb)
    fit_sigma = inflate * math.sqrt(max(0.0, float(grad @ ends.cov @ grad)))
    levels = distinct_levels(samples.disparity[line.support])
    quant = quantization_sigma(dist, float(z.mean()), fb, quantum, levels, line.sigma_d)
    click_1px = _click_term(frame, xy1, xy2, d_end, ends.slope, dist, 1.0)
    click = options.click_px * click_1px if options.click_px > 0 else 0.0
    model = 0.0
    if ends.several:
        reasons.append("segment crosses several surfaces")
        # The one-line answer is the alternative model; part of the way to it is the model-choice error.
        z1 = fb / (np.array([line.at(0.0), line.at(length)]) + frame.doffs)
        if (z1 > 0).all():
            model = MODEL_SHARE * abs(float(np.linalg.norm(r2 * z1[1] - r1 * z1[0])) - dist)
    structure = math.hypot(grad[0] * ends.offsets[0], grad[1] * ends.offsets[1])
    sensor2 = fit_sigma**2 + quant**2 + model**2 + structure**2
    # Weakly supported samples carry less information: the fit term grows by the effective sample
    # size (measure.confidence). The decisions below keep the plain terms, so answers stay the same.
    fit_weak = fit_sigma * support_inflation(samples.confidence, line.support)
    sigma = calibrated_sigma(math.sqrt(sensor2 - fit_sigma**2 + fit_weak**2 + click**2), dist)
    # Whether the line says little (IMPRECISE, below) is judged at a mouse's click whatever the stated
    # click error: the same clicks answer the same, only the uncertainty follows options.click_px.
    sigma_line = calibrated_sigma(math.sqrt(sensor2 + (DECISION_CLICK_PX * click_1px) ** 2), dist)
    parts = {"fit": fit_weak, "click": click, "quant": quant, "model": model, "structure": structure}
    q1f, q2f, gap = q1, q2, False
    if options.gap_detection:
        # The gap question is about the segment's own surface (the global line), whatever an end's
        # piece says; each end's surface is its extension and the segment's samples in front of the line next to it.
        res = samples.disparity - line.at(t)
        k1 = leading_run(res, line.support)
        k2 = leading_run(res[::-1], line.support[::-1])
        cov_g = line.cov_at(0.0, length)
        se_g = (inflate * math.sqrt(max(0.0, float(cov_g[0, 0]))), inflate * math.sqrt(max(0.0, float(cov_g[1, 1]))))
        ends_s = clear_gap_ends(frame, xy1, xy2, options.extension_px, (samples.disparity[:k1], samples.disparity[::-1][:k2]),
                                (line.at(0.0), line.at(length)), se_g, quantum)
        if ends_s is not None:
            zg1, zg2 = (fb / (e.disparity + frame.doffs) for e in ends_s)
            g1, g2 = r1 * zg1, r2 * zg2
            gd = float(np.linalg.norm(g2 - g1))
            ext_sigma = endpoint_depth_sigma(g1, g2, zg1 * zg1 / fb * ends_s[0].se, zg2 * zg2 / fb * ends_s[1].se)
            # What limits a gap's width: its end surfaces' depths (their noise and their rounding) and
            # the clicks (a click off by a pixel stays on its end's surface), all shrinking as the camera
            # comes closer. The segment's own surface (no gap) is not counted, its rounding neither: at a
            # doorway it is metres behind the ends (docs/decisions/gap-sigma.md).
            quant_g = endpoint_depth_sigma(g1, g2, zg1 * zg1 / fb * ends_s[0].rounding, zg2 * zg2 / fb * ends_s[1].rounding)
            click_g = _click_term(frame, xy1, xy2, np.array([e.disparity for e in ends_s]), np.zeros(2), gd, options.click_px)
            sigma = calibrated_sigma(math.sqrt(ext_sigma**2 + quant_g**2 + click_g**2), gd, GAP_SIGMA_SCALE)
            parts = {"fit": ext_sigma, "click": click_g, "quant": quant_g, "model": 0.0, "structure": 0.0}
            warnings.append("gap detected: both ends' surfaces are in front of the segment's; measured at their depths")
            reasons = [r for r in reasons if r != "segment crosses several surfaces"] + ["gap detected"]
            q1f, q2f, gap = g1, g2, True
    out = float(np.linalg.norm(q2f - q1f))
    if len(samples.points) < FEW_SAMPLES or len(samples.points) < FEW_SHARE * samples.n_samples:
        reasons.append("few valid samples")
    if low_confidence(samples.confidence):
        reasons.append(LOW_CONFIDENCE_REASON)
    if not gap and (on_edge(frame, xy1, xy2, d_end[0]) or on_edge(frame, xy2, xy1, d_end[1])):
        reasons.append("end point on a depth edge")
    if not basic.ok or extrapolated(t, line.support, length, ends.own, EXTRAPOLATED_PX):
        reasons.append("end point extrapolated")
    other = disagreement(out, basic.distance_m)
    if other:
        reasons.append(other)
    fit = "constant-depth" if line.beta == 0.0 and not ends.several else ("surfaces" if ends.several else "line")
    if not gap and not ends.several and basic.ok and sigma_line > IMPRECISE * out:
        # The line says little here (short, sparse or full of wrong matches); click windows off any
        # depth edge, with the standard error of one matching window, measure the same two points.
        edge = on_surface_edge(frame, xy1, xy2, basic.disparity[0]) or on_surface_edge(frame, xy2, xy1, basic.disparity[1])
        bs = basic.uncertainty_m * options.window
        if not edge and math.isfinite(bs) and bs < sigma_line:
            return window_measurement(basic, "robust", t0, samples, tuple(warnings) + ("imprecise line; basic answer",), support=line.support,
                                       reasons=[r for r in reasons if not r.startswith("methods disagree")], window_sigma=bs)
    if terms is not None:
        terms.update(parts)
    return measurement(q1f, q2f, "robust", "none" if gap else fit, basic, sigma, samples, line.support, gap, warnings, t0, reasons)


def _censored(t: np.ndarray, d: np.ndarray, line: DisparityLine, quantum: float) -> DisparityLine:
    """The line's support on a few quantized levels: the interval-censored line (``measure.censored``)
    replaces the least-squares one (which fits the staircase's step, not the line under it)."""
    sup = line.support
    if int(sup.sum()) < MIN_FIT_SAMPLES or not few_levels(d[sup], quantum):
        return line
    inflate = correlation_inflation(d[sup] - line.at(t[sup]))
    fit = censored_line(t[sup], d[sup], quantum, inflate)
    if fit is None:
        return line
    alpha, beta, cov = fit
    if abs(beta) >= abs(line.beta):
        # Steeper than least squares: no step bias to correct (a minority level at an end, one wrong match
        # or a click's slip onto the next surface, is a hard crossing to the censored likelihood). The line
        # stays; its error is its mean squared one under the censored posterior.
        dev = np.array([line.alpha - alpha, line.beta - beta])
        return replace(line, param_cov=cov + np.outer(dev, dev))
    return replace(line, alpha=alpha, beta=beta, param_cov=cov)


def _neighbourhood_ends(frame: Frame, xy1, xy2, ends: EndModels, quantum: float, noise: float) -> EndModels:
    """An end whose piece along the segment disagrees with the global line but gave no line of its own
    (``EndModels.pieces``) takes the robust plane of the image around its click (``measure.neighbourhood``)
    when that plane is off the line's value by more than DISAGREE_REL, on the piece's side: that end
    lies on a surface of its own, seen beside the segment as well as on it."""
    if not any(ends.pieces):
        return ends
    d_end, slope, cov = ends.d_end.copy(), ends.slope.copy(), ends.cov.copy()
    own = list(ends.own)
    for e, (a, b) in enumerate(((xy1, xy2), (xy2, xy1))):
        off = ends.pieces[e]
        if off == 0.0 or own[e]:
            continue
        plane = end_plane(frame.disparity, lambda v: valid_disparity(frame, v), a, b, quantum)
        # As for an own line (measure.surfaces): a surface, not a spread of wrong matches.
        if plane is None or plane.sigma > LOCAL_ROUGHNESS * noise:
            continue
        step = plane.disparity - d_end[e]
        if abs(step) <= DISAGREE_REL * abs(d_end[e]) or step * off <= 0:
            continue
        d_end[e] = plane.disparity
        slope[e] = plane.slope if e == 0 else -plane.slope
        _independent(cov, e, plane.se**2)
        own[e] = True
    if own == list(ends.own):
        return ends
    return replace(ends, d_end=d_end, slope=slope, cov=cov, own=(own[0], own[1]))


def _observed_ends(frame: Frame, xy1, xy2, basic: BasicEnds, t: np.ndarray, line, length: float, ends: EndModels, window: int) -> EndModels:
    """An end on the global line (no surface of its own) that no supporting sample comes near (farther
    than EXTRAPOLATED_PX and 15 % of the length: the line's value there is an extrapolation of its
    slope) takes its click window's median disparity instead, when the window is off a surface edge
    (``_on_surface_edge``) and within DISAGREE_REL of the line's value (the same surface: a window
    farther off is another surface or wrong matches, which ``measure.surfaces`` judges). Its variance
    is that of one matching window (the window's standard error times ``window``, as the imprecise-
    line rule counts it): SGBM's smooth windows look more precise than they are."""
    if not basic.ok:
        return ends
    d_end, cov = ends.d_end.copy(), ends.cov.copy()
    limit = max(EXTRAPOLATED_PX, 0.15 * length)
    ts = t[line.support]
    changed = False
    for e, (a, b, te) in enumerate(((xy1, xy2, 0.0), (xy2, xy1, length))):
        if ends.own[e] or ts.size == 0 or float(np.abs(ts - te).min()) <= limit:
            continue
        dw = basic.disparity[e]
        sw = basic.disparity_se[e] * window
        # A window scattered over more than IMPRECISE of its disparity says less than the line.
        if not sw <= IMPRECISE * abs(dw) or abs(dw - d_end[e]) > DISAGREE_REL * abs(d_end[e]) or on_surface_edge(frame, a, b, dw):
            continue
        d_end[e] = dw
        _independent(cov, e, sw**2)
        changed = True
    return replace(ends, d_end=d_end, cov=cov) if changed else ends


def _independent(cov: np.ndarray, e: int, variance: float) -> None:
    """End ``e`` now has a depth of its own: its error, ``variance`` (px²), is independent of the other end's."""
    cov[e, :] = 0.0
    cov[:, e] = 0.0
    cov[e, e] = variance


def _clean_ends(frame: Frame, xy1, xy2, window: int, ends: EndModels) -> EndModels:
    """An end plainly inside one surface (``surfaces.clean_window_disparity``) whose window depth is
    more than DISAGREE_REL away from its model's: the click's own surface wins (measure.surfaces).
    Every other field is kept: the other end's piece flag is ``_neighbourhood_ends``'s to read."""
    d_end, cov = ends.d_end.copy(), ends.cov.copy()
    own = list(ends.own)
    for e, (a, b) in enumerate(((xy1, xy2), (xy2, xy1))):
        if own[e]:
            continue
        dw = clean_window_disparity(frame.disparity, lambda v: valid_disparity(frame, v), a, b, window)
        if math.isfinite(dw) and abs(dw - d_end[e]) > DISAGREE_REL * abs(d_end[e]):
            d_end[e] = dw
            _independent(cov, e, (CLEAN_SPREAD * abs(dw)) ** 2 / window)
            own[e] = True
    if own == list(ends.own):
        return ends
    return replace(ends, d_end=d_end, cov=cov, own=(own[0], own[1]))
