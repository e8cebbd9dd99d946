"""The sides of a box's top face: where its colour image steps, taken where its depth says an edge is (m, px).

The depth finds a top face's sides only roughly: block matching fattens a face into the background
beyond a depth step (up to ``FATTEN_REACH_PX``), contention eats into it, and across a crease the
side face stays within the top plane's tolerance for a few to tens of pixels. The colour image steps
at the edge to within a pixel, but also inside the face (tape, print) and beyond it (a side face seen
at a grazing angle, floor seams). So each side of the rectangle found from the face's outline is
placed in two steps, on profiles across it on the top plane (Eq. 2, 9; docs/decisions/box-edges.md):

1. The depth edge: the first offset beyond ``-FATTEN_REACH_PX`` (of the outline) where the median
   residual to the top plane leaves its tolerance, and what lies beyond it: a *step* (the disparity
   falls away from the trend just inside: background, or a side face too steep to tell) or a *crease*
   (it goes on smoothly: a side face), whose start is the hinge of the residual's median.
2. The image edge: the colour gradient's magnitude across the side, averaged over each of up to
   ``SEGMENTS`` stretches of it; in each, the strong significant peaks within the depth's window: a
   step's edge lies inside its depth edge by at most the fattening reach, and beyond it lie the
   fattened background's features, so the innermost is taken; a crease's lies within twice that
   reach inside its hinge (the ridge is flattened too), not beyond it, and inside it lie the top's
   own features, so the outermost. A line through the stretches' peaks that most of them agree on is the side, with
   its tilt. A side without one keeps its depth edge moved inward by half the fattening reach, with
   that reach as its uncertainty, and makes the answer one to check (measure.box).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.planes import INLIER_SIGMAS, Plane

FATTEN_REACH_PX = 8.0
STEP_PX = 0.5
SEGMENTS = 6
SEGMENT_PROFILES = 16
SEGMENT_PROFILES_MIN = 8
SIDE_SPAN = 0.8
LINE_TOL_PX = 1.5
MIN_SEGMENTS = 3
AGREE_SHARE = 0.6
STEP_TOLS = 1.0
SEARCH_SHARE = 0.4
PEAK_SIGMAS = 5.0
PEAK_RATIO = 1.6
STRONG_SHARE = 0.5
EDGE_PX = 0.5
CREASE_RESIDUAL = 4.0
CREASE_GAIN = 25.0
CREASE_BINS = 5
CORRELATED_PX = 4.0
MIN_SIDE_POINTS = 8

# Side k of a rectangle: (along axis, across axis, sign of the outward direction along it).
AXES = ((1, 0, 1.0), (1, 0, -1.0), (0, 1, 1.0), (0, 1, -1.0))


@dataclass(frozen=True)
class RectFrame:
    """A rectangle's frame on a plane: ``pc`` (3D point, m), in-plane unit vectors ``u``, ``v``, the
    rectangle's centre ``centre`` (2D in u, v, m) and its axes ``e`` (2 x 2 rows, in u, v)."""

    pc: np.ndarray
    u: np.ndarray
    v: np.ndarray
    centre: np.ndarray
    e: np.ndarray

    def to_3d(self, s: np.ndarray) -> np.ndarray:
        """3D points (..., 3, m) of rectangle coordinates ``s`` (..., 2, m)."""
        q = np.asarray(s, float) @ self.e + self.centre
        return self.pc + q[..., :1] * self.u + q[..., 1:] * self.v

    def to_px(self, top: Plane, s: np.ndarray) -> np.ndarray:
        """Image pixels (..., 2) of rectangle coordinates ``s`` (..., 2, m)."""
        p = self.to_3d(s)
        return np.stack([top.fx * p[..., 0] / p[..., 2] + top.cx, top.fy * p[..., 1] / p[..., 2] + top.cy], -1)


@dataclass(frozen=True)
class Side:
    """One side's position (m from the rectangle's centre along its outward axis), one-sigma (m), how
    it was found ("image", or from the depth alone: "crease" at a hinge, "depth" at a depth edge), its
    tilt against the rectangle's axis (rad, as the slope of its across-coordinate along it; 0 when not
    from the image) and that tilt's weight (the stretches that agree on it), whether a side face goes on
    beyond it (a crease, not a depth step) and its pixel's footprint across it (m)."""

    pos: float
    sigma: float
    source: str
    tilt: float
    tilt_weight: float
    crease: bool
    foot: float


@dataclass(frozen=True)
class _Grid:
    xy: np.ndarray  # profiles x offsets x 2 (px)
    t: np.ndarray  # offsets (px of the side's footprint)
    along: np.ndarray  # profiles' positions along the side, from its middle (m)
    foot: float  # m per px across the side


def _grid(top: Plane, rf: RectFrame, pos: np.ndarray, k: int, t: np.ndarray) -> _Grid:
    """Profiles across side ``k`` over its middle ``SIDE_SPAN``, one per pixel along it (at most
    ``SEGMENTS`` x ``SEGMENT_PROFILES``), sampled at offsets ``t`` (px of its footprint) from ``pos[k]``."""
    along, across, sign = AXES[k]
    lo, hi = (-pos[3], pos[2]) if along == 1 else (-pos[1], pos[0])
    mid, half = (lo + hi) / 2.0, (hi - lo) / 2.0
    p0 = np.zeros(2)
    p0[along], p0[across] = mid, sign * pos[k]
    da, dc = np.zeros(2), np.zeros(2)
    da[along], dc[across] = 1e-3, sign * 1e-3
    a, b, c = rf.to_px(top, np.stack([p0, p0 + dc, p0 + da]))
    foot = 1e-3 / max(float(np.linalg.norm(b - a)), 1e-9)
    foot_along = 1e-3 / max(float(np.linalg.norm(c - a)), 1e-9)
    n = int(np.clip(2.0 * SIDE_SPAN * half / foot_along, SEGMENTS * 2, SEGMENTS * SEGMENT_PROFILES))
    al = np.linspace(-SIDE_SPAN * half, SIDE_SPAN * half, n)
    s = np.zeros((n, len(t), 2))
    s[..., along] = mid + al[:, None]
    s[..., across] = sign * (pos[k] + t[None, :] * foot)
    return _Grid(rf.to_px(top, s), t, al, foot)


def _sample_image(image: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear colour samples (profiles x offsets x 3, float) at ``xy`` and which lie in the image."""
    import cv2

    h, w = image.shape[:2]
    inside = (xy[..., 0] >= 0) & (xy[..., 0] <= w - 1) & (xy[..., 1] >= 0) & (xy[..., 1] <= h - 1)
    x0 = int(np.clip(np.floor(xy[..., 0].min()) - 1, 0, w - 1))
    y0 = int(np.clip(np.floor(xy[..., 1].min()) - 1, 0, h - 1))
    x1 = int(np.clip(np.ceil(xy[..., 0].max()) + 2, x0 + 1, w))
    y1 = int(np.clip(np.ceil(xy[..., 1].max()) + 2, y0 + 1, h))
    roi = image[y0:y1, x0:x1].astype(np.float32)
    mx = (xy[..., 0] - x0).astype(np.float32)
    my = (xy[..., 1] - y0).astype(np.float32)
    return cv2.remap(roi, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), inside


def _residuals(frame, top: Plane, xy: np.ndarray) -> np.ndarray:
    """Disparity minus the top plane's (px) at the pixels nearest ``xy``; NaN off the image or without depth."""
    h, w = frame.shape
    xi, yi = np.rint(xy[..., 0]).astype(np.int64), np.rint(xy[..., 1]).astype(np.int64)
    ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    d = np.full(xi.shape, np.nan)
    d[ok] = frame.disparity[yi[ok], xi[ok]]
    return d - top.disparity_at(xi, yi)


def _column_median(a: np.ndarray) -> np.ndarray:
    """Median of each column of ``a`` over its finite values (NaN for a column without any)."""
    srt = np.sort(a, axis=0)  # NaN sorts last
    n = np.isfinite(a).sum(axis=0)
    cols = np.arange(a.shape[1])
    lo, hi = np.maximum((n - 1) // 2, 0), np.maximum(n // 2, 0)
    out = 0.5 * (srt[lo, cols] + srt[hi, cols])
    out[n == 0] = np.nan
    return out


def _depth_edge(t: np.ndarray, r: np.ndarray, tol: float) -> float:
    """Where the top plane's support ends along the offsets ``t`` (px): the first offset beyond
    ``-FATTEN_REACH_PX`` from which the residual's median over the profiles stays off the plane
    (beyond ``tol``) for a pixel; the median keeps contention's outliers (up to half) out of it."""
    med = _column_median(r)
    off = ~(np.abs(med) <= tol)  # NaN (no depth across the profiles) counts as off
    run = off[:-2] & off[1:-1] & off[2:]
    idx = np.flatnonzero(run & (t[:-2] >= -FATTEN_REACH_PX))
    return float(t[idx[0]] - STEP_PX / 2.0) if idx.size else float(t[-1])


def _is_step(t: np.ndarray, r: np.ndarray, t_d: float, tol: float) -> bool:
    """Whether the disparity beyond the depth edge ``t_d`` (px) jumps away from the top plane (a step:
    background, or a side face too steep to matter) rather than going on as the residual's trend just
    inside it (a crease): its median over ``FATTEN_REACH_PX`` beyond lies more than ``STEP_TOLS``
    tolerances below that trend's extrapolation, or mostly has no depth."""
    past = r[:, (t > t_d) & (t <= t_d + FATTEN_REACH_PX)]
    valid = np.isfinite(past)
    if past.size == 0 or valid.mean() < 0.5:
        return True
    near = (t >= t_d - 2.0 * FATTEN_REACH_PX) & (t <= t_d - 1.0)
    med = _column_median(r[:, near])
    ok = np.abs(med) <= tol  # the face itself: a jump just inside the edge is no trend
    if ok.sum() >= 3:
        b, a = np.polyfit(t[near][ok], med[ok], 1)
        trend = a + b * (t_d + FATTEN_REACH_PX / 2.0)
    else:
        trend = 0.0
    return float(np.median(past[valid])) < trend - STEP_TOLS * tol


def _hinge(t: np.ndarray, r: np.ndarray, tol: float, noise2: float, lo: float, hi: float) -> float | None:
    """Where a linear fall of the residual ``r`` (profiles x offsets, px) begins: a hinge fit to its
    per-offset medians over [lo, hi] px; None unless the fall is significant, reaches the tolerance
    and is seen over ``CREASE_BINS`` offsets beyond the hinge."""
    keep = np.abs(r) <= CREASE_RESIDUAL * tol
    counts = keep.sum(axis=0)
    med = _column_median(np.where(keep, r, np.nan))
    use = counts >= MIN_SIDE_POINTS
    if use.sum() < CREASE_BINS + 2:
        return None
    tc, mc, w = t[use], med[use], counts[use].astype(float)
    grid = np.arange(lo, hi + 1e-9, 0.25)
    grid = grid[grid < tc.max()]
    if grid.size == 0:
        return None
    hinge = np.maximum(tc[None, :] - grid[:, None], 0.0)
    su, sru = (w * hinge**2).sum(axis=1), (w * hinge * mc).sum(axis=1)
    gain = np.where(su > 0, sru**2 / np.maximum(su, 1e-30), 0.0)
    best = int(np.argmax(gain))
    slope = sru[best] / su[best] if su[best] > 0 else 0.0
    reach = -slope * (tc.max() - grid[best])
    beyond = int((tc > grid[best]).sum())
    if gain[best] > CREASE_GAIN * noise2 and reach >= tol and beyond >= CREASE_BINS:
        return float(grid[best])
    return None


def _peak(g: np.ndarray, tm: np.ndarray, lo: float, hi: float, inner: bool) -> float | None:
    """The innermost (or outermost) significant local maximum (px, sub-pixel) within [lo, hi] of the
    mean gradient profile of ``g`` (profiles x offsets): ``PEAK_SIGMAS`` standard errors above the
    profile's median and ``PEAK_RATIO`` times it."""
    prof = g.mean(axis=0)
    # The texture's noise on the mean, pooled over the offsets (at an edge the profiles' spread also
    # holds the edge's own wander, which would hide it).
    se = float(np.median(g.std(axis=0))) / math.sqrt(max(1, g.shape[0]))
    bg = float(np.median(prof))
    i = np.arange(1, len(prof) - 1)
    ok = (prof[i] >= prof[i - 1]) & (prof[i] >= prof[i + 1]) & (prof[i] > bg + PEAK_SIGMAS * se)
    ok &= (prof[i] > PEAK_RATIO * bg) & (tm[i] >= lo) & (tm[i] <= hi)
    idx = i[ok]
    if idx.size == 0:
        return None
    # Texture beyond a crease (a foreshortened side face) or inside a step's halo makes weak peaks:
    # only those within ``STRONG_SHARE`` of the strongest count.
    rise = prof[idx] - bg
    idx = idx[rise >= STRONG_SHARE * rise.max()]
    j = int(idx.min() if inner else idx.max())
    a, b, c = prof[j - 1], prof[j], prof[j + 1]
    den = a - 2.0 * b + c
    return float(tm[j] + (0.5 * (a - c) / den * STEP_PX if den < 0 else 0.0))


def _line(points: np.ndarray, need: int) -> tuple[float, float, np.ndarray] | None:
    """Line t = t0 + b a through the (a, t) points that most agree within ``LINE_TOL_PX`` (every pair
    tried, then a least-squares fit of its inliers): (t0, b, inliers) or None with fewer than ``need``
    in agreement."""
    n = len(points)
    if n < need:
        return None
    a, t = points[:, 0], points[:, 1]
    i, j = np.triu_indices(n, 1)
    da = a[j] - a[i]
    b = np.where(da != 0, (t[j] - t[i]) / np.where(da != 0, da, 1.0), 0.0)
    t0 = t[i] - b * a[i]
    res = np.abs(t[None, :] - (t0[:, None] + b[:, None] * a[None, :]))
    inl = res <= LINE_TOL_PX
    score = inl.sum(axis=1) - np.where(inl, res, 0.0).sum(axis=1) / (n * LINE_TOL_PX)
    best = inl[int(np.argmax(score))]
    if best.sum() < need:
        return None
    bb, tt = np.polyfit(a[best], t[best], 1)
    return float(tt), float(bb), best


def _depth_window(t: np.ndarray, r: np.ndarray, top: Plane, reach_in: float) -> tuple[float, float, bool, float, bool, bool]:
    """Step 1 on the residuals ``r`` (profiles x offsets ``t``, px): the window (lo, hi, px) where the
    image edge may lie, whether the innermost peak is taken, the depth's own edge (px), whether it is
    a crease's hinge, and whether a side face goes on beyond it."""
    tol = INLIER_SIGMAS * max(top.sigma_px, top.quantum * 0.75)
    t_d = _depth_edge(t, r, tol)
    if _is_step(t, r, t_d, tol):
        return t_d - FATTEN_REACH_PX, t_d + 1.0, True, t_d, False, False
    noise2 = (1.2533 * max(top.sigma_px, top.quantum / math.sqrt(12.0))) ** 2 * CORRELATED_PX
    hinge = _hinge(t, r, tol, noise2, -reach_in, t_d)
    if hinge is not None:
        # The ridge's edge lies inside the hinge (the matcher flattens it), not past it: there lie the
        # side face's own features and, a side face seen at a grazing angle, its foot a few px on.
        return hinge - 2.0 * FATTEN_REACH_PX, min(t_d, hinge) + 1.0, False, hinge, True, True
    return t_d - FATTEN_REACH_PX, t_d + 1.0, True, t_d, False, True


def _image_line(frame, grid: _Grid, lo: float, hi: float, inner: bool) -> tuple[float, float, float, int] | None:
    """Step 2: the line (offset at the side's middle px, slope px per m along it, one-sigma px, stretches
    agreeing) through the stretches' image peaks within [lo, hi] px, or None."""
    img, inside = _sample_image(frame.image, grid.xy)
    g = np.linalg.norm(np.diff(img, axis=1), axis=2) / STEP_PX
    tm = grid.t[:-1] + STEP_PX / 2.0
    n = len(grid.along)
    segments = int(np.clip(n // SEGMENT_PROFILES_MIN, MIN_SEGMENTS, SEGMENTS))
    peaks = []
    for q in range(segments):
        sl = slice(q * n // segments, (q + 1) * n // segments)
        rows = inside[sl].all(axis=1)  # profiles that leave the image have no step to show
        if rows.sum() < 2:
            continue
        p = _peak(g[sl][rows], tm, lo, hi, inner)
        if p is not None:
            peaks.append((float(grid.along[sl][rows].mean()), p))
    fit = _line(np.array(peaks), max(MIN_SEGMENTS, math.ceil(AGREE_SHARE * segments))) if peaks else None
    if fit is None:
        return None
    t0, b, inl = fit
    pts = np.array(peaks)[inl]
    spread = float(np.std(pts[:, 1] - (t0 + b * pts[:, 0])))
    return t0, b, math.hypot(EDGE_PX, spread / math.sqrt(inl.sum())), int(inl.sum())


def find_side(frame, top: Plane, rf: RectFrame, pos: np.ndarray, k: int, outline_sigma: float) -> Side:
    """Side ``k`` of the rectangle ``rf`` on the plane ``top`` whose sides lie at ``pos`` (m, from the
    face's outline), placed as the module docstring says; ``outline_sigma`` (m) is the outline's own
    one-sigma for that side, part of the depth's when the image shows no edge."""
    probe = _grid(top, rf, pos, k, np.zeros(1))
    reach_in = max(2.0 * FATTEN_REACH_PX, SEARCH_SHARE * (pos[k] + pos[k ^ 1]) / probe.foot)
    grid = _grid(top, rf, pos, k, np.arange(-reach_in, 2.0 * FATTEN_REACH_PX + 1e-9, STEP_PX))
    lo, hi, inner, depth_t, hinge, crease = _depth_window(grid.t, _residuals(frame, top, grid.xy), top, reach_in)
    line = _image_line(frame, grid, lo, hi, inner)
    if line is None:
        # The edge lies inside the depth's (a step's fattening, a crease's flattened ridge) by up to the reach.
        sigma = math.hypot(outline_sigma, FATTEN_REACH_PX / math.sqrt(12.0) * grid.foot)
        return Side(pos[k] + (depth_t - FATTEN_REACH_PX / 2.0) * grid.foot, sigma, "crease" if hinge else "depth", 0.0, 0.0,
                    crease, grid.foot)
    t0, b, sig_px, agree = line
    return Side(pos[k] + t0 * grid.foot, sig_px * grid.foot, "image", math.atan(AXES[k][2] * b * grid.foot), float(agree),
                crease, grid.foot)
