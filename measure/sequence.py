"""One measurement from several frames of a still scene (one viewpoint, the same two clicks).

Inputs: ``frames`` in time order (the last is the newest, the one the clicks were made on), all
from one camera (same size, intrinsics in px, baseline in m); clicked pixels (x, y). Output: one
:class:`Measurement` (metres) with ``frames_used`` and ``single_frame_uncertainty_m``.

1. **Per frame**: the robust answer of every frame (``robust.robust_with_terms``).
2. **Motion check** (``still_frames``): an older frame joins only if, against the newest, (a) the
   image around each click and around the segment's middle has not shifted (a Lucas-Kanade step on
   blurred ``PATCH_PX`` grey patches: shift at most ``MOTION_PX`` or within four standard errors),
   and (b) the disparity in a band around each half of the segment has not changed by more than
   ``MOTION_DEPTH_REL`` of itself or four standard errors. Only the unbroken run of still frames
   ending at the newest is pooled, and only when the move before it was a step; a gradual move pools
   nothing. Either way the reasons say "scene moved (...): k of N frames pooled".
3. **Pooling** (``pool``): "samples" puts the segment samples of all still frames into one robust
   fit (the end windows, edges and gap extensions of the newest frame); "fits" combines the
   per-frame end depths on the clicks' rays by Tukey's bisquare (``robust_range.tukey_location``). A
   pooled fit whose model (line, surfaces, gap) most frames do not choose falls back to "fits".
4. **Uncertainty** (``pooled_sigma``): the single-frame model's terms (``measure.uncertainty``) of the
   newest frame and of the pooled fit, each pooled as what it is: the click term whole (``click_px``:
   None = ``options.click_px`` calibrated with the rest; a number is the caller's knowledge and enters
   the 95 % interval as a normal error, ``Z95`` sigmas); quantization and model choice never averaged;
   the fit term times the design effect sqrt(1 + (N - 1) rho), rho the static share of the scatter
   (``static_share``); the structure term's bias b² = (N s_N² - mean s_i²) / (N - 1), at least rho
   mean s_i². The newest frame's sigma and interval cap the pooled ones; "fits" floors sigma at the
   per-frame distances' spread over sqrt(N).

Why these choices, with their measurement on the simulator: docs/decisions/several-frames.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from measure.robust import robust_with_terms
from measure.robust_range import median, tukey_location
from measure.sampling import SegmentSamples, ray, sample_segment, segment_pixels
from measure.types import Frame, MeasureError, MeasureOptions, Measurement
from measure.uncertainty import INTERVAL_SCALE, SIGMA_SCALE, calibrated_sigma, disparity_quantum, interval
from measure.verdict import judge

__all__ = ["MAX_FRAMES", "POOLS", "measure_sequence", "still_frames"]

MAX_FRAMES = 30
POOLS: tuple[str, ...] = ("samples", "fits")
PATCH_PX = 64  # side of the grey patches compared for image motion
BLUR_PX = 2.0  # Gaussian blur (px) of those patches: widens the shift test's reach, damps pixel noise
MOTION_PX = 0.5  # image shift (px) beyond which a frame counts as moved: a third of a click's error
BAND_PX = 6  # rows (columns) either side of the segment compared for depth motion
BLOCK_PX = 2.0  # side of the blocks in which disparity errors come (the sim's aux cameras: 2x2 px)
STEP_SHARE = 0.75  # share of a move that one frame step must hold to count as a move that ended
QUIET_SHARE = 1 / 3  # ... while the frames after it stay below this share of it
MOTION_DEPTH_REL = 0.01  # relative change of the segment's disparity level beyond which it moved
MOTION_SIGMAS = 4.0
MIN_SHARE_PX = 10  # pixels valid in every frame needed to tell static from fresh scatter
Z95 = 1.96  # a normal error's 95 % half-width in sigmas (the clicks' part of the interval)
OUTLIER_SIGMAS = 4.0  # robust sigmas beyond which a pixel's residual is a wrong match, not scatter


def _check_frames(frames: Sequence[Frame]) -> list[Frame]:
    frames = list(frames)
    if not frames:
        raise MeasureError("no frames given; pass at least the frame the points were clicked on")
    if len(frames) > MAX_FRAMES:
        raise MeasureError(f"{len(frames)} frames given; pool at most {MAX_FRAMES} (a still scene lasts a few seconds)")
    ref = frames[-1]
    for i, f in enumerate(frames):
        if not isinstance(f, Frame):
            raise MeasureError(f"frames[{i}] must be a measure.Frame, got {type(f).__name__}")
        if f.shape != ref.shape or f.camera != ref.camera or f.baseline_m != ref.baseline_m or f.doffs != ref.doffs:
            raise MeasureError(f"frames[{i}] comes from another camera or calibration than the newest frame; pool frames of one source")
    return frames


def _grey(frame: Frame, cx: float, cy: float) -> np.ndarray | None:
    h, w = frame.shape
    r = PATCH_PX // 2
    x0, y0 = int(round(cx)) - r, int(round(cy)) - r
    x0, y0 = min(max(0, x0), w - PATCH_PX), min(max(0, y0), h - PATCH_PX)
    if x0 < 0 or y0 < 0:
        return None
    p = frame.image[y0 : y0 + PATCH_PX, x0 : x0 + PATCH_PX].astype(np.float32)
    return p @ np.array([0.114, 0.587, 0.299], np.float32)  # BGR -> luma


def image_shift(a: Frame, b: Frame, points: Sequence[tuple[float, float]]) -> float:
    """Largest significant image shift (px) between frames ``a`` and ``b`` over grey patches centred
    on ``points``: one Lucas-Kanade step on patches blurred by ``BLUR_PX`` (a first-order fit of
    b - a to a's gradient), counted only where it exceeds ``MOTION_SIGMAS`` of its own standard error
    (a patch without texture says nothing; why not phase correlation: docs/decisions/several-frames.md)."""
    import cv2

    worst = 0.0
    for x, y in points:
        pa, pb = _grey(a, x, y), _grey(b, x, y)
        if pa is None or pb is None:
            continue
        pa = cv2.GaussianBlur(pa, (0, 0), BLUR_PX)
        pb = cv2.GaussianBlur(pb, (0, 0), BLUR_PX)
        gy, gx = np.gradient(pa)
        m = slice(4, -4)  # away from the blur's border
        g = np.stack([gx[m, m].ravel(), gy[m, m].ravel()], axis=1).astype(np.float64)
        diff = (pb - pa)[m, m].ravel().astype(np.float64)
        gtg = g.T @ g
        if np.linalg.cond(gtg) > 1e6:
            continue
        d = -np.linalg.solve(gtg, g.T @ diff)  # b(x) = a(x - d): b - a = -g . d
        resid = diff + g @ d
        # Blurred pixels are correlated over about the blur's width: count (2 BLUR_PX)² pixels as one.
        cov = float(resid @ resid) / max(1, len(diff) - 2) * np.linalg.inv(gtg) * (2 * BLUR_PX) ** 2
        se = math.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0))
        shift = math.hypot(*d)
        if shift > MOTION_SIGMAS * se:
            worst = max(worst, shift)
    return worst


def depth_change(ref: Frame, other: Frame, p1: tuple[float, float], p2: tuple[float, float]) -> tuple[float, float]:
    """Largest relative change of the disparity from ``ref`` to ``other`` over the two halves of a band
    around the segment (robust location of the paired per-pixel differences over the reference level;
    a turning object moves one end nearer and the other farther), and its limit: ``MOTION_DEPTH_REL``
    or ``MOTION_SIGMAS`` standard errors, whichever is larger. NaN when a half has < 5 pixel pairs."""
    seg = segment_pixels(p1[0], p1[1], p2[0], p2[1])
    # A band of BAND_PX rows (or columns) either side of the segment: more pixels, a finer test.
    across = np.array([0, 1]) if abs(p2[0] - p1[0]) >= abs(p2[1] - p1[1]) else np.array([1, 0])
    offs = np.arange(-BAND_PX, BAND_PX + 1)
    half = np.arange(len(seg)) < len(seg) / 2
    px = (seg[None, :, :] + offs[:, None, None] * across).reshape(-1, 2)
    first = np.broadcast_to(half, (len(offs), len(seg))).ravel()
    h, w = ref.shape
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    px, first = px[inside], first[inside]
    a = ref.disparity[px[:, 1], px[:, 0]].astype(np.float64)
    b = other.disparity[px[:, 1], px[:, 0]].astype(np.float64)
    ok = ref.valid(a) & other.valid(b)
    worst, worst_limit = math.nan, math.nan
    for part in (first, ~first):
        sel = ok & part
        if sel.sum() < 5:
            return math.nan, math.nan
        level = float(median(a[sel]))
        # Bisquare location, not the median: on quantized disparity the median jumps a whole step.
        change, se = tukey_location(b[sel] - a[sel])
        se *= BLOCK_PX  # sensors and matchers decide in blocks: one pixel in BLOCK_PX² is independent
        rel, limit = change / level, max(MOTION_DEPTH_REL, MOTION_SIGMAS * se / level)
        if not abs(rel) / limit <= abs(worst) / worst_limit:  # NaN on the first half: take it
            worst, worst_limit = rel, limit
    return worst, worst_limit


def _motion(ref: Frame, other: Frame, p1, p2, mid) -> tuple[float, str]:
    """How far ``other`` moved against ``ref`` in units of its limit (> 1: moved), and the words for it."""
    shift = image_shift(ref, other, (p1, mid, p2))
    change, limit = depth_change(ref, other, p1, p2)
    depth = abs(change) / limit if math.isfinite(change) else 0.0  # no common pixels: no evidence of motion
    if shift / MOTION_PX >= depth:
        return shift / MOTION_PX, f"image moved by {shift:.1f} px"
    return depth, f"depth moved by {100 * abs(change):.1f} %"


def still_frames(frames: Sequence[Frame], p1: tuple[float, float], p2: tuple[float, float]) -> tuple[int, list[str]]:
    """How many of the newest frames form an unbroken still run (module docstring, step 2), and why
    it ends. A move that ended (a step) keeps the run after it: the first moved frame (walking back
    from the newest) must differ from its newer neighbour, the run's oldest frame, by at least
    ``STEP_SHARE`` of its motion score, and no frame of the run may score above ``QUIET_SHARE`` of it.
    Otherwise the scene moves gradually, each frame by less than the test sees, the run drifts too,
    and only the newest frame is used."""
    frames = list(frames)
    ref = frames[-1]
    mid = (0.5 * (p1[0] + p2[0]), 0.5 * (p1[1] + p2[1]))
    quiet = 0.0
    for j in range(1, len(frames)):
        older = frames[-1 - j]
        score, why = _motion(ref, older, p1, p2, mid)
        if score <= 1.0:
            quiet = max(quiet, score)
            continue
        if j > 1 and quiet <= QUIET_SHARE * score and _motion(frames[-j], older, p1, p2, mid)[0] >= STEP_SHARE * score:
            return j, [f"{why} {j} frames back"]
        return 1, [f"{why} {j} frames back; the scene is moving"]
    return len(frames), []


def _pooled_samples(frames: Sequence[Frame], p1, p2) -> SegmentSamples:
    parts = [sample_segment(f, p1, p2) for f in frames]
    return SegmentSamples(
        n_samples=sum(p.n_samples for p in parts),
        pixels=np.concatenate([p.pixels for p in parts]),
        disparity=np.concatenate([p.disparity for p in parts]),
        points=np.concatenate([p.points for p in parts]),
        confidence=None if any(p.confidence is None for p in parts) else np.concatenate([p.confidence for p in parts]),
    )


def measure_sequence(
    frames: Sequence[Frame],
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
    pool: str = "samples",
    click_px: float | None = None,
) -> Measurement:
    """Distance (m) between clicked pixels ``p1``, ``p2`` pooled over the still ``frames`` (oldest first;
    the newest last); see the module docstring. Only the robust method pools; raises MeasureError.

    Only the newest unbroken run of frames without image shift or depth change is pooled. Pooling
    shrinks the sensor's part of the error, not the clicks' (docs/eval/frames/report.md measures both).

    Args:
        frames: frames of one camera, oldest first, all with the same (H, W) float32 disparity (px)
            and intrinsics.
        p1: first click (x, y) in the newest frame (pair of floats, px).
        p2: second click (x, y) (px).
        options: measurement options; ``options.method`` must be ``"robust"``.
        pool: ``"samples"`` (one robust fit on the pooled samples) or ``"fits"`` (Tukey location of the
            per-frame end depths) (str).
        click_px: one-sigma error of the clicks along the segment (px); None: ``options.click_px``, with
            the single-frame model's calibration. A number replaces ``options.click_px`` (same bounds) and
            is taken as the caller's knowledge (the click part outside the calibration, see the module
            docstring); 0 for clicks known to be exact (detected corners, a replayed annotation): the
            click term then drops out of the uncertainty.

    Returns:
        A :class:`measure.Measurement` of the newest frame with ``frames_used`` and
        ``single_frame_uncertainty_m`` set (m).

    Raises:
        MeasureError: no frames, mismatched frames, an unknown ``pool``, a method other than robust, or
            the newest frame cannot be measured.

    Examples:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera
        >>> from measure.sequence import measure_sequence
        >>> cam = PinholeCamera(fx=60.0, fy=60.0, cx=31.5, cy=23.5, width=64, height=48)
        >>> disparity = np.full((48, 64), 12.0, dtype=np.float32)  # a plane 0.5 m away
        >>> frame = Frame(np.zeros((48, 64, 3), np.uint8), disparity, cam, baseline_m=0.1)
        >>> m = measure_sequence([frame, frame, frame], (10, 24), (54, 24))
        >>> print(m.frames_used, round(m.distance_m, 4))
        3 0.3667
    """
    frames = _check_frames(frames)
    if pool not in POOLS:
        raise MeasureError(f"pool={pool!r} is unknown; use one of {', '.join(POOLS)}")
    if options.method != "robust":
        raise MeasureError(f"only the robust method pools several frames, not method={options.method!r}; use method='robust' or one frame")
    stated = click_px is not None
    if stated:
        options = replace(options, click_px=click_px)  # validated there: a MeasureError names the value
    ref = frames[-1]
    single, terms = robust_with_terms(ref, p1, p2, options)
    if stated and terms:
        single = _with_sigma(single, _reported(_sensor2(terms), terms.get("click", 0.0), stated, single.distance_m))
    if len(frames) == 1:
        return _with_frames(single, single, 1, [])
    run, why = still_frames(frames, _xy(p1), _xy(p2))
    still = frames[len(frames) - run :]
    reasons = [f"scene moved ({why[0]}): {run} of {len(frames)} frames pooled"] if why else []
    if run == 1:
        return _with_frames(single, single, 1, reasons)
    per, per_terms = [single], [terms]
    for f in reversed(still[:-1]):
        try:
            m, t = robust_with_terms(f, p1, p2, options)
        except MeasureError:
            break  # a frame without data along the segment ends the run: the pooled frames stay the newest ones
        per.append(m)
        per_terms.append(t)
    per.reverse()
    still = still[len(still) - len(per) :]
    dists = np.array([m.distance_m for m in per])
    n = len(per)
    pooled, pooled_terms = robust_with_terms(ref, p1, p2, options, _pooled_samples(still, p1, p2))
    kinds, notes = [(m.fit, m.gap_detected) for m in per], []
    if pool == "samples" and kinds.count((pooled.fit, pooled.gap_detected)) * 2 <= n:
        # A repeated error (a static wrong-match pattern at an edge) counts n times in the pooled samples
        # and can make a surface or gap "significant" that most frames alone do not show: their fits decide.
        pool = "fits"
        notes = [f"pooled fit chose {pooled.fit}{' (gap)' if pooled.gap_detected else ''}, most frames not: per-frame fits combined"]
        pooled_terms = {**terms, "fit": terms.get("fit", 0.0) / math.sqrt(n)} if terms else {}
    if pool == "samples":
        out = pooled
        q1, q2 = np.array(out.p1_m), np.array(out.p2_m)
    else:
        out = single
        z = np.array([[m.p1_m[2], m.p2_m[2]] for m in per])
        z1, z2 = tukey_location(z[:, 0])[0], tukey_location(z[:, 1])[0]
        r1, r2 = ray(ref, *p1), ray(ref, *p2)
        same_rays = all(np.allclose(np.array(m.p1_m) / m.p1_m[2], r1) and np.allclose(np.array(m.p2_m) / m.p2_m[2], r2) for m in per)
        if same_rays:
            q1, q2 = r1 * z1, r2 * z2
        else:  # window (basic) answers keep their own end pixels: combine the distances instead
            q1, q2 = np.array(single.p1_m), np.array(single.p2_m)
            scale = tukey_location(dists)[0] / single.distance_m
            mid = 0.5 * (q1 + q2)
            q1, q2 = mid + (q1 - mid) * scale, mid + (q2 - mid) * scale
    dist = float(np.linalg.norm(q2 - q1))
    rho = static_share(still, _xy(p1), _xy(p2))
    single_half = single.interval_m[1] - single.distance_m
    if terms and pooled_terms and all(per_terms):
        sigma, half = pooled_sigma(terms, pooled_terms, rho, [t.get("structure", 0.0) for t in per_terms], dist, stated)
        if pool == "fits":  # a mean of per-frame answers is no better than their spread says
            floor = float(np.std(dists, ddof=1)) / math.sqrt(n)
            half, sigma = half * max(1.0, floor / sigma) if sigma > 0 else half, max(sigma, floor)
        # The mean of still frames is never less precise than one of them: the newest frame's caps it.
        sigma, half = min(sigma, max(single.uncertainty_m, calibrated_sigma(0.0, dist))), min(half, single_half)
    else:  # a window (basic) answer has no terms: nothing is known to average
        sigma, half = single.uncertainty_m, single_half
    return _with_frames(out, single, n, reasons, q1, q2, (sigma, half), dists, notes)


def _xy(p: tuple[float, float]) -> tuple[float, float]:
    """A click as a pair of floats (the API hands lists)."""
    return float(p[0]), float(p[1])


def static_share(frames: Sequence[Frame], p1: tuple[float, float], p2: tuple[float, float]) -> float:
    """Share rho in [0, 1] of the disparity scatter about the segment's surface that repeats in every
    frame (the same error at the same pixel: fixed patterns, repeated wrong matches, a surface that is
    not the line, noise-free rounding), from the pixels valid in all ``frames``: one minus the mean
    within-pixel variance over frames (fresh noise) over the variance about a line fitted to the
    per-pixel medians (fresh + static). 1 when fewer than ``MIN_SHARE_PX`` pixels say (no evidence
    that anything averages)."""
    seg = segment_pixels(p1[0], p1[1], p2[0], p2[1])
    h, w = frames[-1].shape
    seg = seg[(seg[:, 0] >= 0) & (seg[:, 0] < w) & (seg[:, 1] >= 0) & (seg[:, 1] < h)]
    d = np.stack([f.disparity[seg[:, 1], seg[:, 0]].astype(np.float64) for f in frames])
    ok = np.all(np.stack([f.valid(row) for f, row in zip(frames, d)]), axis=0)
    d, t = d[:, ok], np.arange(len(seg), dtype=np.float64)[ok]
    if t.size < MIN_SHARE_PX:
        return 1.0
    med = np.median(d, axis=0)
    keep = np.ones(t.size, bool)
    for _ in range(2):  # least squares, then again without the pixels a wrong match took
        coef = np.polyfit(t[keep], med[keep], 1)
        res = med - np.polyval(coef, t)
        keep = np.abs(res - np.median(res[keep])) <= OUTLIER_SIGMAS * max(1.4826 * float(np.median(np.abs(res[keep] - np.median(res[keep])))), 1e-9)
    r = d[:, keep] - np.polyval(coef, t[keep])
    # A wrong match (contention) would count as scatter of whole pixels: entries beyond OUTLIER_SIGMAS
    # robust sigmas are left out (a repeated one leaves its pixel without evidence), the scale floored
    # at the disparity step, below which quantized residuals give no MAD.
    scale = max(1.4826 * float(np.median(np.abs(r - np.median(r)))), disparity_quantum(d[np.isfinite(d)]))
    r = np.where(np.abs(r - np.median(r)) <= OUTLIER_SIGMAS * scale, r, np.nan)
    k = np.isfinite(r).sum(axis=0)
    r = r[:, k >= 2]
    if r.shape[1] < MIN_SHARE_PX:
        return 1.0
    total = float(np.nanvar(r, ddof=1))
    fresh = float(np.nanmean(np.nanvar(r, axis=0, ddof=1)))
    return float(min(1.0, max(0.0, 1.0 - fresh / total))) if total > 0 else 1.0


def _reported(sensor2: float, click: float, stated: bool, dist: float) -> tuple[float, float]:
    """Reported one-sigma and 95 % half-width (m) from the model's sensor variance ``sensor2`` (m²) and
    click term ``click`` (m, at ``options.click_px``). Not ``stated``: the single-frame model as it
    stands, both calibrated together (``calibrated_sigma``, ``interval``). Stated (measure_sequence's
    ``click_px``), the click term is the caller's knowledge, not a model output: only the sensor
    part carries the calibration (one sigma ``SIGMA_SCALE``, the interval ``INTERVAL_SCALE`` model
    sigmas: real stereo's heavy tail), the click part one sigma and ``Z95`` sigmas."""
    if not stated:
        sigma = calibrated_sigma(math.sqrt(sensor2 + click * click), dist)
        return sigma, interval(dist, sigma)[1] - dist
    sensor = calibrated_sigma(math.sqrt(sensor2), dist)
    return math.hypot(sensor, click), math.hypot(INTERVAL_SCALE / SIGMA_SCALE * sensor, Z95 * click)


def _sensor2(terms: dict[str, float]) -> float:
    return sum(v * v for k, v in terms.items() if k != "click")


def _with_sigma(m: Measurement, sigma_half: tuple[float, float]) -> Measurement:
    sigma, half = sigma_half
    return replace(m, uncertainty_m=float(sigma), interval_m=(max(0.0, m.distance_m - half), m.distance_m + half))


def pooled_sigma(terms: dict[str, float], pooled_terms: dict[str, float], rho: float, structure: Sequence[float],
                 dist: float, stated: bool = False) -> tuple[float, float]:
    """Reported one-sigma (m) of the pooled answer (module docstring, step 4) from the newest frame's
    model ``terms``, the model ``pooled_terms`` of the fit on the pooled samples, the static share
    ``rho`` (:func:`static_share`), every pooled frame's structure term ``structure`` (m, one per
    frame), the pooled distance ``dist`` (m) and whether the click term was ``stated`` by the caller; and the 95 %
    half-width (m)."""
    n = len(structure)
    # The pooled fit counts every frame's samples as independent; the static share repeats in every
    # frame, so its variance is n times too small there (the design effect 1 + (n - 1) rho).
    fit2 = pooled_terms.get("fit", 0.0) ** 2 * (1.0 + (n - 1) * rho)
    # Shared by every frame, never averaged: the rounding levels (the larger of the newest frame's
    # term and the pooled fit's, whose dithering may say less) and the model choice.
    shared2 = max(terms.get("quant", 0.0), pooled_terms.get("quant", 0.0)) ** 2 + pooled_terms.get("model", 0.0) ** 2
    # Residual structure next to the ends: a possible bias of the line there. Noise alone also leaves
    # the nearest samples' median off the line (E s_1² = b² + v per frame, E s_N² = b² + v / n pooled),
    # which the fit term already holds; only the part that persists over the frames is a bias b².
    s_n2 = pooled_terms.get("structure", 0.0) ** 2
    s_i2 = np.array(structure, dtype=np.float64) ** 2
    # The pooled samples' nearest ones need not be the same pixels (duplicates crowd the end), so the
    # static share rho of the scatter repeats in the structure too: at least rho of its per-frame size.
    if n > 1 and np.isfinite(s_i2).all():
        bias2 = max(min(s_n2, max(0.0, (n * s_n2 - float(s_i2.mean())) / (n - 1))), rho * float(s_i2.mean()))
    else:
        bias2 = s_n2
    # The clicks: the same error in every frame, the newest frame's term.
    return _reported(fit2 + shared2 + bias2, terms.get("click", 0.0), stated, dist)


def _with_frames(out: Measurement, single: Measurement, n: int, reasons: list[str], q1=None, q2=None,
                 sigma_half: tuple[float, float] | None = None, dists: np.ndarray | None = None, notes: Sequence[str] = ()) -> Measurement:
    if q1 is None:
        q1, q2 = np.array(out.p1_m), np.array(out.p2_m)
    dist = float(np.linalg.norm(np.asarray(q2) - np.asarray(q1)))
    sigma, half = (out.uncertainty_m, out.interval_m[1] - out.distance_m) if sigma_half is None else sigma_half
    lo, hi = max(0.0, dist - half), dist + half
    base = [r for r in out.reasons if not r.startswith("uncertainty above")]
    warnings = list(out.warnings) + list(notes)
    if dists is not None and len(dists) > 1:
        warnings.append(f"{n} frames: per-frame distances {1e3 * float(dists.min()):.0f}-{1e3 * float(dists.max()):.0f} mm")
    quality, why = judge(base + reasons, out.n_valid, dist, 0.5 * (hi - lo))
    return replace(
        out,
        distance_m=dist,
        p1_m=tuple(float(v) for v in q1),
        p2_m=tuple(float(v) for v in q2),
        uncertainty_m=float(sigma),
        interval_m=(lo, hi),
        quality=quality,
        reasons=why,
        warnings=tuple(warnings),
        frames_used=n,
        single_frame_uncertainty_m=float(single.uncertainty_m),
    )
