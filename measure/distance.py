"""Point-to-point 3D measurement (docs/method.md): the "basic", "paper" and "robust" methods.

Inputs: a :class:`Frame` (disparity in px, intrinsics in px, baseline in m) and two clicked
pixels (x, y) of its colour image. Output: a :class:`Measurement` in metres.

- ``basic``: window-median disparity at each click, Eq. 2, |P1 - P2|.
- ``paper``: docs/method.md steps 1-6 as published: sample the segment (step 1), FAST-MCD with
  h = support_fraction * N on the 3D points (step 2), exact-fit branches (step 3: a = b = 0 ->
  Z of P1, P2 set to -d/c and Eq. 2; other planes -> perpendicular projection, Eq. 4-5),
  otherwise projection of the window end points P1, P2 onto the first principal component
  (step 4, Eq. 6-7), gap detection with Tukey-bisquare ranges of the 25-px extensions (step
  6: on a gap, the basic answer). The degenerate plane through the camera centre (all
  samples on one image line) is not the surface: the line is fit inside it (``linefit``).
- ``robust`` (default): the same samples, but each end point is taken on the clicked pixel's
  viewing ray, at the depth of the robust line there. The clicked pixel is exact; the depth at
  it is the least reliable of all (object edges, mixed pixels, holes), so the window depth is
  not used. The line is fit as disparity along the segment, d(t) = alpha + beta t, which is
  exactly the 3D line in the plane of the viewing rays, with the noise where it is
  (``measure.dline``: FAST-MCD start, Tukey IRLS). This also measures when a clicked pixel has
  no depth (warning "endpoint has no depth within window", the extrapolation visible in the
  uncertainty). One line is a model, not a fact: ``measure.surfaces`` checks the samples next to
  each end against the line and gives an end that lies on a surface of its own (a piece of at
  least 15 px, 10 % or more off the line) that surface's robust line, still on the clicked
  pixel's ray (fit "surfaces"). Gap detection (``measure.gap.is_clear_gap``) asks, at each end, for a
  surface of at least 10 samples (the extension and the segment's samples in front of its line
  next to the click) 15 % nearer than the segment's own surface and by two correlation-inflated
  standard errors; a detected gap is measured between the clicks' rays at those surfaces' depths. Every answer carries a calibrated one-sigma,
  a 95 % interval (``measure.uncertainty``) and a verdict with reasons (``measure.verdict``);
  ``basic`` and ``paper`` answers get a verdict too.

Why these choices (A = 100 - 100 |g - m| / g, mean over measurements unless noted):

- End points on the clicks' viewing rays, with the line fit as disparity d(t) (``measure.dline``),
  vs the same rays met by the paper's 3D TLS line (``measure.linefit``), vs the paper's
  perpendicular projection of the window end points. Synthetic posters (tests/measure_synth.py,
  2/4/6/7 m, wall 0.6 m behind, 1/4 px, contention, 1.5 px jitter, 48 cases): d-line rays 98.39,
  3D-line rays 96.50, paper 93.95, basic 97.74. The 3D TLS line is tilted by the depth noise
  that runs along the rays (worst at 7 m: 97.03 vs 91.81), so the d-line model was kept.
- Final figures (tests/measure/test_measure_accuracy.py: wall 2 m behind, 50 % contention, 3 px jitter,
  80 cases): robust 96.78, paper 86.77, basic 73.54 (per distance in bench/RESULTS.md).
  Middlebury, SGBM (left band filled), 49 GT edge-to-edge segments x 3 clicks
  (tests/measure/test_middlebury_accuracy.py): median robust 98.63, paper 97.85, basic 97.91; mean
  97.51 / 91.54 / 61.78.
- Stress protocol (issue #12; evaluation/stress_middlebury.py and stress_sim.py: exact, jittered,
  inside, piece, long and no-gap click pairs on SGBM, StereoBM and ground truth with 50 % uniform
  outliers; simulated rooms, person, posters, doorways). Dev Middlebury scenes (Adirondack, Piano,
  Playroom, Shelves), before -> after this model selection, gap rule, window fallback and
  calibration, SGBM: share A < 90 13.1 -> 9.8 %, 1σ/2σ coverage of the truth 7.5/13.7 ->
  76.0/90.2 %, gap fired on no-gap segments 35.4 -> 0 %, robust A < 90 where basic >= 90 in
  2.2 %; "good" 61.4 % of answers, "good" with A < 90 4.2 % of all, 2σ coverage among "good"
  87.8 %. Held-out scenes (Motorcycle, Pipes, Recycle, Teddy), SGBM: 1σ/2σ 79.2/93.5 %, good
  61.6 %, good & A < 90 2.0 %. Simulated rooms across wall, board and floor (dev seeds, 72 pairs):
  mean A 85.1 / 94.5 / -14.0 -> 95.0 / 96.9 / 91.9 for wall-board-floor / wall-floor /
  board-floor (basic 98.8 / 95.6 / 98.6; held-out seeds 96.3 / 98.7 / 95.1, basic 98.1 / 95.4 /
  97.5); no dev room answer is "good" with A < 90. Posters (98.21) and person height (97.66, +2.3 %
  on average) unchanged; doorways found in 95.8 % (held-out 83.3 %) with the evidence gap rule
  (``measure.gap``; 91.7 % with the first pass's fixed 20 % step), which also answers one dev
  wall-to-floor segment as a gap (wall-floor 98.0 -> 96.9). The second pass (the bullets on
  extrapolated ends, an end's surface beside the segment, nearest-sample levels in
  ``measure.surfaces`` and the line's second start in ``measure.dline``), SGBM dev: A < 90 8.7 %,
  robust much worse than basic 0.8 % (held-out 1.6 %), 1σ/2σ 80.4/91.3 %, good 60.6 %, good &
  A < 90 3.9 %; ground truth + 50 % outliers robust much worse than basic 0.3 % (held-out 2.0 %);
  rooms 97.6 / 98.3 / 94.6 (held-out 96.6 / 98.8 / 95.8); person +1.87 % (held-out +1.48 %); eval
  sim 97.64; edge protocol median 98.92 (SGBM).
- Few quantized levels (``measure.censored``): on integer disparity at 6-7 m the samples along a
  poster often take two levels with one transition; least squares fits the step (about 1.3 px over
  the segment where the truth is 0.35) and puts a yawed poster's ends 0.6 m apart in depth (width
  1.36 m for 0.83). The interval-censored line (each level bounds the value to ±q/2, the noise scale
  marginalised) replaces it where it is flatter; where steeper, the line stays with the censored
  posterior's mean squared error as its covariance. Eval sim, paper profile, seeds 0 / 1 / 2: robust
  95.76 / 95.88 / 95.88 -> 96.55 / 96.56 / 96.73 (std 6.73 / 6.55 / 6.38 -> 4.10 / 4.23 / 3.68), at
  7 m 91.30 / 91.72 / 91.81 -> 93.71 / 93.86 / 94.38, robust - paper -0.06 / -0.08 / -0.07 -> +0.73 /
  +0.61 / +0.78; stress profile 97.55 unchanged; Middlebury SGBM unchanged, ground truth + 50 %
  outliers edge-protocol mean 97.75 -> 97.81; stress-sim within 0.02 points (the alternatives tried
  are in ``measure.censored``). Paper profile seed 0 at 6-7 m, 1σ / 2σ coverage 63.6 / 86.4 -> 80.5 /
  96.2 %, 2σ among "good" 79.3 -> 93.6 %. Bench diagonal (dozens of levels: not used) 1.96 ms CPU.
- Imprecise line, one surface (one sigma above ``IMPRECISE`` = 8 % of the distance, typically a
  short piece full of wrong matches): the click windows answer when neither is on a depth edge and
  their standard error, counted as one sample per matching window, is smaller. Dev stress, SGBM:
  A < 90 10.9 -> 9.8 %, robust much worse than basic 3.9 -> 2.2 %; StereoBM mean A 87.8 -> 96.7.
  "On a depth edge" here means most of the 7 px beyond the click are another surface
  (``_on_surface_edge``): with any one pixel of 3 (the reason phrase's test), scattered wrong
  matches blocked the windows on ground truth with 50 % outliers, where robust was much worse than
  basic in 6.4 / 6.9 % of the dev / held-out stress cases; now 1.7 / 2.5 % (mean A 90.0 -> 96.3 /
  62.2 -> 79.8; SGBM and StereoBM unchanged; "good" with A < 90 0 -> 0.6 / 0.4 %).
- Extrapolated ends (``_observed_ends``): an end no supporting sample comes near (the line's
  support stops more than 5 px and 15 % of the length short of it) takes its click window's median
  when that window is off a surface edge, within 10 % of the line there (the same surface) and
  scattered by at most ``IMPRECISE`` of its disparity (one sample per window; a noisier window once
  made an end's disparity indistinguishable from zero on a 6-m poster frame). The
  common cause of the dev SGBM cases where robust was much worse than basic: SGBM's smooth,
  correlated bias bends the last samples before a click (or leaves a hole there), the bisquare drops
  them as outliers against the tiny per-pixel scale, and the line's slope is extrapolated over
  12-60 px by 1-8 % in disparity. Dev stress, SGBM: robust much worse than basic 2.2 -> 0.8 %
  (held-out 4.1 -> 1.6 %), A < 90 9.8 -> 8.7 % (held-out 11.0 -> 8.6 %), mean A 95.66 -> 95.94;
  StereoBM 1.4 -> 0.6 % (held-out 1.2 -> 0.8 %); GT + 50 % outliers unchanged (its misses are
  segments with fewer than half inliers, beyond the fit's breakdown point); edge protocol median
  98.80 -> 98.96 (SGBM); sim unchanged. The corrected answers land inside 1σ: SGBM dev 1σ / 2σ
  coverage 76.0 / 90.2 -> 80.4 / 91.1 % (no single sigma scale gives <= 76 % and >= 90 % now).
- An end's surface beside the segment (``_neighbourhood_ends``, ``measure.neighbourhood``): when
  an end's piece along the segment disagrees with the line but is too rough or contended for a line
  of its own (one image column through a contended band holds scattered values while the columns
  beside it show the floor plainly), a robust plane over the 12-px half-window around the click on
  the segment's side gives that end's depth, if it scatters no more than an own line may, supports
  half the window and lies beyond 10 % of the line on the piece's side. Sim rooms (dev seeds,
  wall-board-floor / wall-floor / board-floor): 94.99 / 96.90 / 91.93 -> 97.62 / 98.25 / 94.59
  with the nearest-samples level below (basic 98.77 / 95.63 / 98.57; held-out 96.64 / 98.79 /
  95.44, basic 98.10 / 95.43 / 97.53); Middlebury stress unchanged (the piece must hold 10 valid
  samples: with 5, a jittered click off an object in SGBM's occlusion band took the background).
- Per-end surfaces (``measure.surfaces``): a piece needs 15 px (the simulator's touch clicks
  slip up to ~13 px off an object; at 30 px the rooms lose 2-6 points, at 15 px posters are
  unchanged), a smooth, not steep own line inside its data (without these 11 of 1800 eval sim
  answers went to 4-40 m on wrong matches in a contended band) and a 10 % offset (SGBM and
  StereoBM bias the last pixels before an edge by 4-8 % on single Middlebury surfaces; at 4 % the
  single-surface segments switched models in 8 % of the stress cases and lost accuracy). A click
  plainly inside one surface (a clean 5x5 window, no step within 8 px) whose window depth is 10 %
  off the line's takes the window's depth (``_clean_ends``; 13 of 2108 stress cases). The other
  end keeps its piece flag (``EndModels.pieces``) for ``_neighbourhood_ends``; it was once dropped
  with the rebuilt EndModels, which changed no answer of the stress studies, eval sim (1981 robust
  answers) or the edge protocol (none of the 13 had a piece at its other end), but left a contended
  box's end on the wall behind it (tests/measure/test_end_models.py: 1.493 m for 1.595 m).
- Tried and dropped: a click window joining the line's end value by inverse variance wherever the
  line is less precise than the window (sim rooms +0.8 points, but SGBM dev mean A 95.2 -> 89.6:
  SGBM's smooth, fattened windows look precise where they are wrong; hence the one-sample window
  error and the 8 % gate above). A fixed relative gap step alone (10-20 %) is no evidence rule:
  see ``measure.gap`` for the rule that replaced it and its figures. Moving each end by the median
  residual of its nearest supported samples beyond one noise scale (per sample) cost eval sim's
  posters at 6-7 m a point (all targets 97.54 -> 97.26, std 2.45 -> 4.29); beyond two standard
  errors of that median and one disparity quantum (``measure.surfaces``) it costs 0.05 points and
  brings the person height within 2 %.
- Confidence maps: not used. The default SGBM confidence of ``device.sources.sgbm`` is 1.0 on every
  valid pixel, so weighting by it equals dropping invalid pixels, which sampling already does.
  The left-right consistency (``lr_confidence=1``) is graded, but dropping samples below it
  hurts: on the 147 Middlebury clicks robust mean 97.51 -> 93.4 at thresholds 0.3-0.75 and
  89.8 at 0.99 (3-5 click pairs lose every sample; the check removes exactly the edge pixels a
  measurement ends on), basic 61.8 -> 58.4 / 12.0.
- Depth beyond the measurable range: an end's disparity (window median for basic and paper, the
  line's end value for robust) within ``RESOLVED_SIGMAS`` = 2 standard errors of zero has an
  unbounded depth (relative depth error = relative disparity error > 50 %): MeasureError, not an
  answer of 1e31 m with an infinite sigma (fuzz reproduction, disparities of 1e-30 px).
- Fewer than five valid samples along the line: MeasureError, not a basic answer from the end
  windows (on Middlebury, before SGBM's left band was filled, such windows sat in the band's
  edge: A = -145).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from measure.basic import BasicEnds, basic_ends
from measure.gap import end_surface, extension_depth, is_clear_gap, is_gap, leading_run
from measure.geometry import project_on_line, project_on_plane
from measure.censored import censored_line, few_levels
from measure.dline import DisparityLine, fit_disparity_line
from measure.linefit import LineModel, fit_line
from measure.sampling import (
    SegmentSamples,
    backproject,
    backproject_depth,
    check_point,
    ray,
    sample_segment,
    valid_disparity,
    window_median_disparity,
)
from measure.neighbourhood import end_plane
from measure.surfaces import CLEAN_SPREAD, DISAGREE_REL, LOCAL_ROUGHNESS, EndModels, clean_window_disparity, extrapolated, on_depth_edge, select_end_models
from measure.types import Frame, MeasureError, MeasureOptions, Measurement, validate_frame
from measure.uncertainty import (
    MODEL_SHARE,
    calibrated_sigma,
    click_sigma,
    correlation_inflation,
    disparity_quantum,
    endpoint_depth_sigma,
    interval,
    line_fit_sigma,
    quantization_sigma,
)
from measure.verdict import EDGE_PX, EDGE_STEP, EXTRAPOLATED_PX, FEW_SAMPLES, FEW_SHARE, disagreement, judge

__all__ = ["backproject", "measure_distance", "window_median_disparity"]

BASIC_CLICK_SHARE = 1.5  # px: the basic answer's click error, as a share of the segment's pixel length
IMPRECISE = 0.08  # relative one-sigma above which the robust line yields to clean click windows
DECISION_CLICK_PX = 1.5  # px: the click error at which IMPRECISE is judged (a mouse's; calibrated with it)
MIN_FIT_SAMPLES = 5  # fewer valid samples than this cannot support a robust 3-D fit
NO_DEPTH = "endpoint has no depth within window"
BEYOND_RANGE = (
    "depth beyond the measurable range: an end point's disparity is not distinguishable from zero "
    "(infinite depth) for this camera; click on nearer surfaces or check the disparity map's scale"
)
RESOLVED_SIGMAS = 2.0  # an end's disparity must lie this many of its standard errors above zero


def validate_request(frame: Frame, p1: object, p2: object, options: MeasureOptions) -> tuple[tuple[float, float], tuple[float, float]]:
    """Check the frame, options and clicks; return the clicks as floats. Raises MeasureError."""
    if not isinstance(frame, Frame):
        raise MeasureError(f"frame must be a measure.Frame, got {type(frame).__name__}")
    if not isinstance(options, MeasureOptions):
        raise MeasureError(f"options must be a measure.MeasureOptions, got {type(options).__name__}")
    validate_frame(frame)  # validate_camera: every intrinsic finite and in its physical range
    xy1 = check_point(frame, p1, "p1")
    xy2 = check_point(frame, p2, "p2")
    if xy1 == xy2:
        raise MeasureError("p1 and p2 are the same pixel; click two different points")
    return xy1, xy2


def measure_distance(
    frame: Frame,
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
) -> Measurement:
    """Distance (m) between clicked pixels ``p1`` and ``p2`` (x, y) of ``frame`` by ``options.method``.

    The robust and paper methods fit a robust model to the disparity sampled along the segment and
    back-project the clicks with it (docs/method.md, Eq. 2-7; the module docstring has the steps).

    Args:
        frame: colour image with registered disparity; its (H, W) float32 disparity is in px.
        p1: first click (x, y) (pair of floats, px, in the image of W x H).
        p2: second click (x, y) (px).
        options: method, window, support fraction, gap detection and seed.

    Returns:
        A :class:`Measurement`: ``distance_m`` and ``uncertainty_m`` in m, the 3D end points, the
        samples and the verdict.

    Raises:
        MeasureError: bad frame, clicks or options, clicks too close, or no valid disparity to measure from.

    Example:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> disparity = np.full((48, 64), 12.0, dtype=np.float32)  # a plane 0.5 m away
        >>> frame = Frame(np.zeros((48, 64, 3), np.uint8), disparity, cam, baseline_m=0.1)
        >>> from measure import MeasureOptions, measure_distance
        >>> m = measure_distance(frame, (10, 24), (54, 24))  # 44 px at 0.5 m with fx = 60 px
        >>> print(round(m.distance_m, 4), round(m.uncertainty_m, 4), m.fit, m.n_samples)
        0.3667 0.0247 constant-depth 45
        >>> print(round(measure_distance(frame, (10, 24), (54, 24), MeasureOptions(method="basic")).distance_m, 4))
        0.3667
    """
    t0 = time.perf_counter()
    xy1, xy2 = validate_request(frame, p1, p2, options)
    basic = basic_ends(frame, xy1, xy2, options.window)
    # Relative depth error = relative disparity error: at or above 1/RESOLVED_SIGMAS the depth is unbounded.
    unresolved = basic.ok and any(not _resolved(1.0, s / float(p[2])) for s, p in zip(basic.z_sigma, (basic.p1_m, basic.p2_m)))
    if unresolved and options.method in ("basic", "paper"):
        raise MeasureError(BEYOND_RANGE)
    if options.method == "basic":
        if not basic.ok:
            raise MeasureError(f"{NO_DEPTH}: the basic method needs depth at both clicks; click on a surface with depth or use method='robust'")
        edge = any(_on_edge(frame, a, b, d) for a, b, d in ((xy1, xy2, basic.disparity[0]), (xy2, xy1, basic.disparity[1])))
        return _basic_measurement(basic, "basic", t0, reasons=["end point on a depth edge"] if edge else [])
    samples = sample_segment(frame, xy1, xy2)
    if samples.n_samples < MIN_FIT_SAMPLES:
        raise MeasureError(
            f"p1 and p2 are only {samples.n_samples - 1} px apart: too short for a robust fit; "
            "click farther apart or use method='basic'"
        )
    if len(samples.points) < MIN_FIT_SAMPLES:
        # Depth at the end windows alone, with none along the line, is not worth a number.
        raise MeasureError(
            f"no valid disparity along the segment from p1 to p2 (only {len(samples.points)} valid samples, "
            f"{MIN_FIT_SAMPLES} needed); measure where the depth map has data, or use method='basic'"
        )
    if options.method == "paper" and not basic.ok:
        raise MeasureError(f"{NO_DEPTH}: the paper's method needs depth at both clicks; use method='robust'")
    if options.method == "paper":
        model = fit_line(samples.points, options.support_fraction, options.seed)
        return _paper(frame, xy1, xy2, options, basic, samples, model, t0)
    return _robust(frame, xy1, xy2, options, basic, samples, t0)


def _fb(frame: Frame) -> float:
    return frame.camera.fx * frame.baseline_m


def _click_term(frame: Frame, xy1, xy2, d_end: np.ndarray, slope: np.ndarray, dist: float, click_px: float) -> float:
    return click_sigma(lambda x, y: ray(frame, x, y), xy1, xy2, d_end, slope, _fb(frame), frame.doffs, dist, click_px)


def _on_edge(frame: Frame, start, other, d_end: float) -> bool:
    return on_depth_edge(frame.disparity, lambda v: valid_disparity(frame, v), start, other, float(d_end), EDGE_STEP, EDGE_PX)


def _on_surface_edge(frame: Frame, start, other, d_end: float) -> bool:
    """Most of the 2 EDGE_PX + 1 pixels beyond ``start`` on another surface (scattered wrong matches are not an edge)."""
    return on_depth_edge(frame.disparity, lambda v: valid_disparity(frame, v), start, other, float(d_end), EDGE_STEP, 2 * EDGE_PX + 1, majority=True)


def _quant_term(frame: Frame, samples: SegmentSamples, model: LineModel, p1: np.ndarray, p2: np.ndarray) -> float:
    dist = float(np.linalg.norm(p2 - p1))
    levels = int(np.unique(samples.disparity[model.support]).size)
    mean_z = 0.5 * float(p1[2] + p2[2])
    return quantization_sigma(dist, mean_z, _fb(frame), disparity_quantum(samples.disparity), levels)


def _paper(frame, xy1, xy2, options, basic: BasicEnds, samples, model: LineModel, t0) -> Measurement:
    P1, P2 = basic.p1_m, basic.p2_m
    if model.kind == "constant-depth":
        ends = backproject_depth(frame, np.array([xy1[0], xy2[0]]), np.array([xy1[1], xy2[1]]), np.full(2, model.depth))
        q1, q2 = ends[0], ends[1]
        sigma = _quant_term(frame, samples, model, q1, q2)
    elif model.kind == "plane":
        q1, q2 = project_on_plane(P1, model.plane), project_on_plane(P2, model.plane)
        sigma = _quant_term(frame, samples, model, q1, q2)
    else:
        T, v = model.point, model.direction
        q1, q2 = project_on_line(P1, T, v), project_on_line(P2, T, v)
        fit = line_fit_sigma(
            lambda t, vv: (project_on_line(P1, t, vv), project_on_line(P2, t, vv)),
            T, v, model.scatter, samples.points[model.support],
        )
        # The window end points' own depth errors move them along their rays; the part
        # along v survives the projection.
        along = [abs(float((P / P[2]) @ v)) * s for P, s in zip((P1, P2), basic.z_sigma)]
        sigma = math.sqrt(fit**2 + along[0] ** 2 + along[1] ** 2 + _quant_term(frame, samples, model, q1, q2) ** 2)
    warnings: list[str] = []
    reasons: list[str] = []
    if len(samples.points) < FEW_SAMPLES or len(samples.points) < FEW_SHARE * samples.n_samples:
        reasons.append("few valid samples")
    if options.gap_detection:
        ext = (extension_depth(frame, xy1, xy2, options.extension_px), extension_depth(frame, xy2, xy1, options.extension_px))
        if is_gap(ext, (float(q1[2]), float(q2[2]))):
            return _basic_measurement(basic, "paper", t0, samples, ("gap detected: both extensions are in front of the end points; basic answer",), gap=True, support=model.support, reasons=reasons)
    # The projected end points leave the clicked pixels: the distance between them is a second opinion.
    other = disagreement(float(np.linalg.norm(q2 - q1)), basic.distance_m)
    if other:
        reasons.append(other)
    return _measurement(q1, q2, "paper", model.kind, basic, sigma, samples, model.support, False, warnings, t0, reasons)


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
    out = _robust(frame, xy1, xy2, options, basic_ends(frame, xy1, xy2, options.window), samples, time.perf_counter(), terms)
    return out, terms


def _robust(frame, xy1, xy2, options, basic: BasicEnds, samples: SegmentSamples, t0, terms: dict[str, float] | None = None) -> Measurement:
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
    d_end = ends.d_end
    warnings: list[str] = []
    reasons: list[str] = []
    if not basic.ok:
        warnings.append(NO_DEPTH + " (measured where the click's viewing ray meets the robust line)")
    if not (d_end + frame.doffs > 0).all():
        if not basic.ok:
            raise MeasureError("the robust line runs to infinite depth at an end point that has no depth; click elsewhere")
        warnings.append("the robust line runs to infinite depth at an end point; basic answer")
        return _basic_measurement(basic, "robust", t0, samples, tuple(warnings), support=line.support, reasons=["end point extrapolated"])
    inflate = correlation_inflation(samples.disparity[line.support] - line.at(t[line.support]))
    floor = quantum / math.sqrt(12.0)
    if not all(_resolved(float(d_end[e]) + frame.doffs, max(inflate * math.sqrt(max(0.0, float(ends.cov[e, e]))), floor)) for e in (0, 1)):
        raise MeasureError(BEYOND_RANGE)
    fb = _fb(frame)
    r1, r2 = ray(frame, *xy1), ray(frame, *xy2)
    z = fb / (d_end + frame.doffs)
    q1, q2 = r1 * z[0], r2 * z[1]
    dist = float(np.linalg.norm(q2 - q1))
    # dD/dd_i = dD/dZ_i * dZ_i/dd_i with dZ/dd = -Z²/(fB); the two fitted disparities are correlated.
    grad = np.array([r1 @ (q1 - q2), r2 @ (q2 - q1)]) / dist * (-(z**2) / fb)
    fit_sigma = inflate * math.sqrt(max(0.0, float(grad @ ends.cov @ grad)))
    levels = int(np.unique(samples.disparity[line.support]).size)
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
    sigma = calibrated_sigma(math.sqrt(sensor2 + click**2), dist)
    # Whether the line says little (IMPRECISE, below) is judged at a mouse's click whatever the stated
    # click error: the same clicks answer the same, only the uncertainty follows options.click_px.
    sigma_line = calibrated_sigma(math.sqrt(sensor2 + (DECISION_CLICK_PX * click_1px) ** 2), dist)
    parts = {"fit": fit_sigma, "click": click, "quant": quant, "model": model, "structure": structure}
    q1f, q2f, gap = q1, q2, False
    if options.gap_detection:
        # The gap question is about the segment's own surface (the global line), whatever an end's
        # piece says; each end's surface is its extension and the segment's samples in front of the line next to it.
        res = samples.disparity - line.at(t)
        k1 = leading_run(res, line.support)
        k2 = leading_run(res[::-1], line.support[::-1])
        ends_s = (
            end_surface(frame, xy1, xy2, options.extension_px, samples.disparity[:k1]),
            end_surface(frame, xy2, xy1, options.extension_px, samples.disparity[::-1][:k2]),
        )
        cov_g = line.cov_at(0.0, length)
        se_g = (inflate * math.sqrt(max(0.0, float(cov_g[0, 0]))), inflate * math.sqrt(max(0.0, float(cov_g[1, 1]))))
        if is_clear_gap(ends_s, (line.at(0.0), line.at(length)), se_g, frame.doffs):
            zg1, zg2 = (fb / (e.disparity + frame.doffs) for e in ends_s)
            g1, g2 = r1 * zg1, r2 * zg2
            gd = float(np.linalg.norm(g2 - g1))
            ext_sigma = endpoint_depth_sigma(g1, g2, zg1 * zg1 / fb * ends_s[0].se, zg2 * zg2 / fb * ends_s[1].se)
            # The alternative is the segment's own surface at both clicks (no gap); a click off by a pixel
            # stays on its end's surface.
            zl = fb / (np.array([line.at(0.0), line.at(length)]) + frame.doffs)
            alt = float(np.linalg.norm(r2 * zl[1] - r1 * zl[0])) if (zl > 0).all() else dist
            click_g = _click_term(frame, xy1, xy2, np.array([e.disparity for e in ends_s]), np.zeros(2), gd, options.click_px)
            sigma = calibrated_sigma(math.sqrt(ext_sigma**2 + quant**2 + click_g**2 + (MODEL_SHARE * abs(gd - alt)) ** 2), gd)
            parts = {"fit": ext_sigma, "click": click_g, "quant": quant, "model": MODEL_SHARE * abs(gd - alt), "structure": 0.0}
            warnings.append("gap detected: both ends' surfaces are in front of the segment's; measured at their depths")
            reasons = [r for r in reasons if r != "segment crosses several surfaces"] + ["gap detected"]
            q1f, q2f, gap = g1, g2, True
    out = float(np.linalg.norm(q2f - q1f))
    if len(samples.points) < FEW_SAMPLES or len(samples.points) < FEW_SHARE * samples.n_samples:
        reasons.append("few valid samples")
    if not gap and (_on_edge(frame, xy1, xy2, d_end[0]) or _on_edge(frame, xy2, xy1, d_end[1])):
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
        edge = _on_surface_edge(frame, xy1, xy2, basic.disparity[0]) or _on_surface_edge(frame, xy2, xy1, basic.disparity[1])
        bs = basic.uncertainty_m * options.window
        if not edge and math.isfinite(bs) and bs < sigma_line:
            return _basic_measurement(basic, "robust", t0, samples, tuple(warnings) + ("imprecise line; basic answer",), support=line.support,
                                      reasons=[r for r in reasons if not r.startswith("methods disagree")], window_sigma=bs)
    if terms is not None:
        terms.update(parts)
    return _measurement(q1f, q2f, "robust", "none" if gap else fit, basic, sigma, samples, line.support, gap, warnings, t0, reasons)


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
        if not sw <= IMPRECISE * abs(dw) or abs(dw - d_end[e]) > DISAGREE_REL * abs(d_end[e]) or _on_surface_edge(frame, a, b, dw):
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


def _check_range(dist: float, sigma: float) -> None:
    """Every answer has a finite distance and a finite, positive sigma (m)."""
    if not (math.isfinite(dist) and math.isfinite(sigma) and sigma > 0):
        raise MeasureError(BEYOND_RANGE)


def _resolved(d: float, se: float) -> bool:
    """A disparity ``d`` (px, doffs included) a depth can be taken from: more than ``RESOLVED_SIGMAS``
    of its standard error ``se`` (px) above zero. Closer to zero, depth = fB/d is unbounded within
    the error (its relative error is above 1/RESOLVED_SIGMAS)."""
    return d > RESOLVED_SIGMAS * se


def _measurement(q1, q2, method, fit, basic: BasicEnds, sigma, samples, support, gap, warnings, t0, reasons=()) -> Measurement:
    dist = float(np.linalg.norm(q2 - q1))
    sigma = calibrated_sigma(float(sigma), dist) if method != "robust" else float(sigma)
    _check_range(dist, sigma)
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


def _basic_measurement(
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
    _check_range(dist, sigma)
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
