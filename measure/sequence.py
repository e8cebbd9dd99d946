"""One measurement from several frames of a still scene (one viewpoint, the same two clicks).

Inputs: ``frames`` in time order (the last is the newest, the one the clicks were made on), all
from one camera (same size, intrinsics in px, baseline in m); clicked pixels (x, y). Output: one
:class:`Measurement` (metres) with ``frames_used`` and ``single_frame_uncertainty_m``.

1. **Per frame**: the robust answer of every frame (``distance.robust_with_terms``).
2. **Motion check** (``still_frames``): an older frame joins only if, against the newest, (a) the
   image around each click and around the segment's middle has not shifted (a Lucas-Kanade step on
   blurred ``PATCH_PX`` grey patches: shift at most ``MOTION_PX`` or within four standard errors),
   and (b) the disparity in a band around each half of the segment has not changed by more than
   ``MOTION_DEPTH_REL`` of itself or four standard errors. Only the unbroken run of still frames
   ending at the newest is pooled, and only when the move before it was a step (the first moved
   frame differs from its newer neighbour by most of the move, and the run's frames are quiet
   against it); a gradual move (every frame a little) pools nothing. Either way the reasons say
   "scene moved (...): k of N frames pooled"; with k = 1 the answer is the newest frame's alone. A
   moving scene is never averaged.
3. **Pooling** (``pool``): "samples" puts the segment samples of all still frames into one robust
   fit (docs/method.md steps 1-6 on the pooled samples; the end windows, edges and gap extensions of the
   newest frame); "fits" combines the per-frame end depths on the clicks' rays by Tukey's bisquare
   (``robust_range.tukey_location``). Chosen by measurement: "samples" (figures below).
4. **Uncertainty**: the single-frame model (``measure.uncertainty``, before its calibration scale)
   splits into a part every frame shares and a part a new frame may draw afresh. Shared, never
   averaged: the click term (the same clicks in every frame), the quantization term (the same
   rounding levels) and the model-choice term. Possibly fresh: the fit and the residual-structure
   terms, which hold both per-frame noise and static errors (edge fattening, a contention pattern
   that repeats, calibration); only the frame-to-frame spread s of the per-frame distances tells
   how much of them is fresh. With sigma_1 the newest frame's model sigma, F² = fit² + structure²:

       sigma_random² = min(s², F²)
       sigma_static² = sigma_1² - sigma_random²
       sigma_N       = SIGMA_SCALE * sqrt(sigma_static² + sigma_random² / N)

   i.e. pooling removes (1 - 1/N) of only what was seen to vary. s from N frames is uncertain: its
   lower one-sigma bound (chi-square, N - 1 degrees of freedom) sets what is removed from sigma_1,
   its upper bound what is added back over N, so three frames do not claim what ten would; the
   newest frame's own sigma caps the result. The 95 % interval is ``measure.uncertainty.interval``.

Figures (``depthruler eval frames``, docs/eval/frames/report.md: the poster's width and length at
2/4/6/7 m, 8 still 10-frame scenes per distance, target and contention kind). At 6-7 m, N = 1 -> 10,
std of A / mean A / 95 % coverage: clicks on the true end pixels, fresh contention 0.42 -> 0.08 /
99.59 -> 99.92 / 100 -> 100 %, static contention 0.45 -> 0.12 / 99.58 -> 99.91 / 100 -> 100 %;
simulated human clicks, fresh 1.77 -> 1.67 / 97.22 -> 97.53 / 94 -> 97 %, static 1.98 -> 1.85 /
97.33 -> 97.47 / 94 -> 97 % (the clicks' error is the same in every frame). Pool "samples" vs "fits"
at N = 10 (exact clicks, fresh / static): std of A 0.08 / 0.12 vs 0.15 / 0.13, hence "samples".
Moving scenes (camera turning 1 px a frame, walking 3 cm a frame, board turning 1 degree a frame):
12 of 12 sequences (24 of 24 with both click kinds) answered from the newest frame alone; still
scenes at 6-7 m: every frame pooled. Phase correlation for the image test locked onto sensor noise
on patches of little texture (4-12 px between still frames at 2 m): replaced by the Lucas-Kanade
step with its standard error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from .distance import robust_with_terms
from .robust_range import median, tukey_location
from .sampling import SegmentSamples, ray, sample_segment, segment_pixels
from .types import Frame, MeasureError, MeasureOptions, Measurement
from .uncertainty import SIGMA_SCALE, calibrated_sigma, interval
from .verdict import judge

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
# chi-square quantiles / dof for 1..29 degrees of freedom at 16 % and 84 % (one-sigma bounds of s²).
_CHI2_DOF = {k: v for k, v in enumerate((
    (0.0199, 1.98), (0.174, 1.83), (0.288, 1.72), (0.372, 1.64), (0.436, 1.59), (0.487, 1.54), (0.529, 1.51),
    (0.563, 1.48), (0.593, 1.45), (0.618, 1.43), (0.640, 1.41), (0.659, 1.39), (0.676, 1.38), (0.691, 1.36),
    (0.705, 1.35), (0.717, 1.34), (0.728, 1.33), (0.738, 1.32), (0.747, 1.31), (0.756, 1.30), (0.764, 1.29),
    (0.771, 1.29), (0.778, 1.28), (0.784, 1.27), (0.790, 1.27), (0.795, 1.26), (0.800, 1.26), (0.805, 1.25),
    (0.809, 1.25)), start=1)}


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
    (a patch without texture says nothing). Phase correlation was tried first: on patches of little
    texture it locked onto the sensor noise and reported 4-12 px shifts between still frames."""
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


def _spread_bounds(values: np.ndarray) -> tuple[float, float]:
    """Lower and upper one-sigma bounds of the variance of ``values`` (chi-square, n - 1 dof)."""
    n = len(values)
    if n < 2:
        return 0.0, 0.0
    s2 = float(np.var(values, ddof=1))
    lo, hi = _CHI2_DOF[min(n - 1, max(_CHI2_DOF))]
    return s2 / hi, s2 / lo


def measure_sequence(
    frames: Sequence[Frame],
    p1: tuple[float, float],
    p2: tuple[float, float],
    options: MeasureOptions = MeasureOptions(),
    pool: str = "samples",
) -> Measurement:
    """Distance (m) between clicked pixels ``p1``, ``p2`` pooled over the still ``frames`` (oldest first;
    the newest last); see the module docstring. Only the robust method pools; raises MeasureError.

    Only the newest unbroken run of frames without image shift or depth change is pooled.

    Args:
        frames: frames of one camera, oldest first, all with the same (H, W) float32 disparity (px)
            and intrinsics.
        p1: first click (x, y) in the newest frame (pair of floats, px).
        p2: second click (x, y) (px).
        options: measurement options; ``options.method`` must be ``"robust"``.
        pool: ``"samples"`` (one robust fit on the pooled samples) or ``"fits"`` (Tukey location of the
            per-frame end depths) (str).

    Returns:
        A :class:`measure.Measurement` of the newest frame with ``frames_used`` and
        ``single_frame_uncertainty_m`` set (m).

    Raises:
        MeasureError: no frames, mismatched frames, an unknown ``pool``, a method other than robust, or
            the newest frame cannot be measured.

    Example:
        >>> import numpy as np
        >>> from measure import Frame, PinholeCamera\n        >>> from measure.sequence import measure_sequence
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
    ref = frames[-1]
    single, terms = robust_with_terms(ref, p1, p2, options)
    if len(frames) == 1:
        return _with_frames(single, single, 1, [])
    run, why = still_frames(frames, _xy(p1), _xy(p2))
    still = frames[len(frames) - run :]
    reasons = [f"scene moved ({why[0]}): {run} of {len(frames)} frames pooled"] if why else []
    if run == 1:
        return _with_frames(single, single, 1, reasons)
    per = [single]
    for f in reversed(still[:-1]):
        try:
            per.append(robust_with_terms(f, p1, p2, options)[0])
        except MeasureError:
            break  # a frame without data along the segment ends the run: the pooled frames stay the newest ones
    per.reverse()
    still = still[len(still) - len(per) :]
    dists = np.array([m.distance_m for m in per])
    n = len(per)
    if pool == "samples":
        out, _ = robust_with_terms(ref, p1, p2, options, _pooled_samples(still, p1, p2))
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
    sigma = pooled_sigma(single.uncertainty_m, terms, dists, dist)
    return _with_frames(out, single, n, reasons, q1, q2, sigma, dists)


def _xy(p: tuple[float, float]) -> tuple[float, float]:
    """A click as a pair of floats (the API hands lists)."""
    return float(p[0]), float(p[1])


def pooled_sigma(single_sigma: float, terms: dict[str, float], dists: np.ndarray, dist: float) -> float:
    """Reported one-sigma (m) of the pooled answer (module docstring, step 4) from the newest frame's
    calibrated ``single_sigma``, its model terms and the per-frame distances ``dists`` (m)."""
    n = len(dists)
    var_lo, var_hi = _spread_bounds(dists)
    model1 = single_sigma / SIGMA_SCALE
    # The same clicks, rounding levels and model choice in every frame: never averaged away.
    floor2 = sum(terms.get(k, 0.0) ** 2 for k in ("click", "quant", "model"))
    floor2 = min(floor2, model1 * model1) if math.isfinite(floor2) else model1 * model1
    removable = model1 * model1 - floor2  # fit and structure: fresh per frame only as far as seen to vary
    static2 = model1 * model1 - min(var_lo, removable)
    random2 = min(var_hi, removable)
    # A wide spread from few frames can bound sigma_random above what was removed; the mean of still
    # frames is never less precise than one of them, so the newest frame's sigma caps it.
    return min(calibrated_sigma(math.sqrt(static2 + random2 / n), dist), max(single_sigma, calibrated_sigma(0.0, dist)))


def _with_frames(out: Measurement, single: Measurement, n: int, reasons: list[str], q1=None, q2=None,
                 sigma: float | None = None, dists: np.ndarray | None = None) -> Measurement:
    if q1 is None:
        q1, q2 = np.array(out.p1_m), np.array(out.p2_m)
    dist = float(np.linalg.norm(np.asarray(q2) - np.asarray(q1)))
    sigma = out.uncertainty_m if sigma is None else sigma
    lo, hi = interval(dist, sigma)
    base = [r for r in out.reasons if not r.startswith("uncertainty above")]
    warnings = list(out.warnings)
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
