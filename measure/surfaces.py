"""Model selection for the robust method: one straight surface, or a surface of its own at each end.

The robust disparity line d(t) = alpha + beta t (``measure.dline``) is the right model when both
clicks lie on one straight surface, the paper's assumption; a segment from a wall down to the floor
is two pieces, and one line puts the other end at the dominant piece's depth.

Steps (``select_end_models``, run on every measurement):

1. Each end's *piece*: the longest leading run of samples next to it of which at most
   ``PIECE_INLIERS`` are supported by the global line (scattered wrong matches do not cut it short).
2. An end *disagrees* when its piece spans at least ``MIN_PIECE_PX`` px with at least ``MIN_LOCAL``
   valid samples and their median residual exceeds max(4 s, ``DISAGREE_REL`` of the end's disparity)
   (s = 1.4826 MAD of the line's support residuals).
3. A disagreeing end gets its own robust line, fit on its piece's samples within ``PIECE_FIT_PX`` of
   the click, if its scatter is at most ``LOCAL_ROUGHNESS`` times the main surface's, its disparity
   changes by at most ``MAX_PIECE_CHANGE`` across the piece, it supports ``LOCAL_SUPPORT`` of the
   piece and it differs from the global line at the click by the same threshold; the end's depth is
   that line's at the click, still on the clicked pixel's ray.
4. A disagreeing piece without such a line but dense along the segment (``_dense_span``: 15 px
   without a hole wider than 7.5 px) is reported in ``EndModels.pieces`` for
   ``measure.neighbourhood``.
5. An end on the global line whose supported samples in the segment's last tenth sit, by their
   median, more than ``NEAR_SIGMAS`` standard errors (1.2533 s / sqrt(k), inflated for lag-one
   correlation), one disparity quantum and from at least ``MIN_LOCAL`` samples off the line takes that
   level; otherwise the offset is an uncertainty term only.

``on_depth_edge`` and ``clean_window_disparity`` read the image around a click. Why these
thresholds: docs/decisions/end-surfaces.md. Units: t, window in px along the segment; disparities in px.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.dline import DisparityLine, fit_disparity_line
from measure.robust_range import median
from measure.uncertainty import correlation_inflation

MIN_LOCAL = 10  # fewer valid samples than this in an end's piece: no line of its own
MIN_PIECE_PX = 15  # a shorter piece is a click that slipped off the surface, not a surface of its own
PIECE_INLIERS = 0.1  # an end's piece: a leading run at most this share of which the global line supports
PIECE_FIT_PX = 40.0  # an end's own line is fit on the piece's part nearest the click
DISAGREE_REL = 0.1  # relative disparity (= depth) offset an end's piece must show (module docstring)
DISAGREE_SIGMAS = 4.0
MAX_PIECE_CHANGE = 0.5  # an own line may change its disparity by at most half across its piece
LOCAL_ROUGHNESS = 3.0  # an own line may scatter at most this many times the main surface's noise
NEAR_SIGMAS = 2.0  # an end's nearest supported samples move it when their median is this many standard errors off
LOCAL_SUPPORT = 0.5  # share of its piece an end's own line must support: a surface, not scattered outliers


def _piece_length(support: np.ndarray) -> int:
    """Length of the longest leading run of samples of which at most PIECE_INLIERS are supported."""
    share = np.cumsum(support) / np.arange(1, len(support) + 1)
    hit = np.flatnonzero(share <= PIECE_INLIERS)
    return int(hit[-1]) + 1 if hit.size else 0


def _dense_span(dist: np.ndarray) -> float:
    """Span (px) of the samples at distances ``dist`` from a click (nearest first) up to the first hole
    wider than MIN_PIECE_PX / 2: a surface seen along the segment, not samples scattered across a hole."""
    if dist.size == 0:
        return 0.0
    holes = np.flatnonzero(np.diff(dist) > 0.5 * MIN_PIECE_PX)
    last = int(holes[0]) if holes.size else dist.size - 1
    return float(dist[last] - dist[0])


@dataclass(frozen=True)
class EndModels:
    """Disparity at each end (px), its slope along t, the 2x2 covariance of the two end disparities,
    and which ends have a line of their own."""

    d_end: np.ndarray
    slope: np.ndarray
    cov: np.ndarray
    own: tuple[bool, bool]
    offsets: tuple[float, float]  # median residual (px) of the samples nearest each end from its model
    # Median residual (px) of an end's piece that disagrees with the global line but yields no line of
    # its own (too few samples along the segment, rough, steep...); 0 elsewhere. ``measure.neighbourhood``
    # looks for that end's surface in the image around the click.
    pieces: tuple[float, float] = (0.0, 0.0)

    @property
    def several(self) -> bool:
        return any(self.own)


def select_end_models(t: np.ndarray, d: np.ndarray, length: float, line: DisparityLine, quantum: float, seed: int) -> EndModels:
    """Per-end model choice of the module docstring for samples at ``t`` (px, 0 = p1, ``length`` = p2,
    in segment order)."""
    d_end = np.array([line.at(0.0), line.at(length)], dtype=np.float64)
    slope = np.array([line.beta, line.beta])
    cov = line.cov_at(0.0, length)
    r = d - line.at(t)
    own = [False, False]
    pieces = [0.0, 0.0]
    local_cov = [0.0, 0.0]
    n = len(t)
    # The noise scale of the line's support (MAD: the RMS of a bisquare support is inflated by the
    # half-fitting samples of another surface).
    scale = 1.4826 * median(np.abs(r[line.support])) if line.support.any() else line.sigma_d
    for e in (0, 1):
        k = _piece_length(line.support if e == 0 else line.support[::-1])
        if k < MIN_LOCAL or k > n - MIN_LOCAL:  # no piece, or no global line left beside it
            continue
        sel = slice(0, k) if e == 0 else slice(n - k, n)
        if abs(float(t[sel][-1] - t[sel][0])) < MIN_PIECE_PX:
            continue
        off = median(r[sel])
        thr = max(DISAGREE_SIGMAS * scale, DISAGREE_REL * abs(float(d_end[e])))
        if abs(off) <= thr:
            continue
        ts = np.abs(t[sel] - (0.0 if e == 0 else length))
        ts = ts if e == 0 else ts[::-1]  # nearest the click first
        if _dense_span(ts) >= MIN_PIECE_PX:
            pieces[e] = off
        if k < MIN_LOCAL:
            continue
        te = 0.0 if e == 0 else length
        near = np.abs(t[sel] - te) <= PIECE_FIT_PX
        if near.sum() < MIN_LOCAL:
            near = np.ones(k, bool)
        local = fit_disparity_line(t[sel][near], d[sel][near], 0.5, seed, quantum)
        dl = float(local.at(te))
        dp = d[sel][near][local.support]
        if dp.size < MIN_LOCAL // 2 or local.support.mean() < LOCAL_SUPPORT:
            continue  # scattered wrong matches, not a surface
        rough = local.sigma_d > LOCAL_ROUGHNESS * max(scale, quantum / math.sqrt(12.0))
        # A surface's depth does not halve across a few dozen pixels; chance alignments of wrong matches do.
        steep = abs(local.beta) * float(np.ptp(t[sel][near])) > MAX_PIECE_CHANGE * abs(float(dp.mean()))
        # Beyond its own data the line is an extrapolation, not a depth.
        outside = not (dp.min() - 3.0 * local.sigma_d <= dl <= dp.max() + 3.0 * local.sigma_d)
        if rough or steep or outside or abs(dl - d_end[e]) <= thr:
            continue
        d_end[e] = local.at(te)
        slope[e] = local.beta
        local_cov[e] = float(local.cov_at(te, te)[0, 0])
        own[e] = True
        pieces[e] = 0.0
    # Residual structure next to each end: the median residual of the nearest supported samples (a shoe in
    # front of a leg, a rounded head, edge fattening). Beyond NEAR_SIGMAS standard errors of that median
    # (correlation-inflated) the end takes its nearest samples' level; otherwise it is counted in the
    # uncertainty as a possible bias.
    m = max(MIN_LOCAL // 2, n // 10)
    near_off = [0.0, 0.0]
    near_var = [0.0, 0.0]
    if n >= 2 * m:
        for e, sl in ((0, slice(0, m)), (1, slice(n - m, n))):
            sup = r[sl][line.support[sl]]
            if own[e] or not sup.size:
                continue
            near_off[e] = float(median(sup))
            if sup.size < MIN_LOCAL:  # a level needs as many samples as a piece
                continue
            se = 1.2533 * max(scale, quantum / math.sqrt(12.0)) / math.sqrt(sup.size) * correlation_inflation(sup - near_off[e])
            # The median of quantized samples resolves no finer than a step: a smaller offset is no evidence.
            if abs(near_off[e]) > max(NEAR_SIGMAS * se, quantum):
                d_end[e] += near_off[e]
                near_var[e] = se * se
                near_off[e] = 0.0
    cov = cov + np.diag(near_var)
    if any(own):
        # Ends on their own lines are independent of each other and of the global line.
        full = cov.copy()
        for e in (0, 1):
            if own[e]:
                full[e, :] = 0.0
                full[:, e] = 0.0
                full[e, e] = local_cov[e]
        cov = full
    return EndModels(d_end, slope, cov, (own[0], own[1]), (near_off[0], near_off[1]), (pieces[0], pieces[1]))


def on_depth_edge(disparity: np.ndarray, valid_of, start: tuple[float, float], other: tuple[float, float], d_end: float, step: float, px: int, majority: bool = False) -> bool:
    """A disparity more than ``step`` (relative) away from ``d_end`` within ``px`` pixels beyond ``start``
    (away from ``other``): a click there that misses by a pixel or two lands on another surface.
    ``majority``: the median of those pixels is that far away (a surface there, not a scattered wrong match)."""
    x0, y0 = start
    ux, uy = x0 - other[0], y0 - other[1]
    n = float(np.hypot(ux, uy))
    k = np.arange(1, px + 1)
    xs = np.rint(x0 + ux / n * k).astype(int)
    ys = np.rint(y0 + uy / n * k).astype(int)
    h, w = disparity.shape
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    v = disparity[ys[inside], xs[inside]]
    v = v[valid_of(v)]
    if majority:
        return bool(v.size and abs(float(np.median(v)) - d_end) > step * abs(d_end))
    return bool(v.size and (np.abs(v - d_end) > step * abs(d_end)).any())


def extrapolated(t: np.ndarray, support: np.ndarray, length: float, own: tuple[bool, bool], px: float) -> bool:
    """An end farther than ``px`` (and 15 % of the length) from the nearest sample supporting its model
    (its own window's samples for an end with a line of its own)."""
    limit = max(px, 0.15 * length)
    for e, te in enumerate((0.0, length)):
        ts = t if own[e] else t[support]
        if ts.size == 0 or float(np.abs(ts - te).min()) > limit:
            return True
    return False


CLEAN_SPREAD = 0.05  # a clean window's disparities lie within this (relative) of their median
CLEAN_PX = 8  # ... and no depth step within this many pixels of the click along the segment


def clean_window_disparity(disparity: np.ndarray, valid_of, click: tuple[float, float], other: tuple[float, float], window: int) -> float:
    """The median disparity (px) of the ``window`` box at ``click`` when the click is plainly inside one
    surface: every pixel of the box valid, all within CLEAN_SPREAD of their median, and no disparity
    differing by more than 2 CLEAN_SPREAD within CLEAN_PX px either way along the segment; else NaN."""
    h, w = disparity.shape
    r = window // 2
    xi, yi = int(round(click[0])), int(round(click[1]))
    if not (r <= xi < w - r and r <= yi < h - r):
        return float("nan")
    box = disparity[yi - r : yi + r + 1, xi - r : xi + r + 1]
    if not valid_of(box).all():
        return float("nan")
    med = float(median(box.ravel()))  # an odd count: np.median's middle value
    if float(np.abs(box - med).max()) > CLEAN_SPREAD * abs(med):
        return float("nan")
    ux, uy = other[0] - click[0], other[1] - click[1]
    n = float(np.hypot(ux, uy))
    k = np.arange(-CLEAN_PX, CLEAN_PX + 1)
    xs = np.clip(np.rint(click[0] + ux / n * k).astype(int), 0, w - 1)
    ys = np.clip(np.rint(click[1] + uy / n * k).astype(int), 0, h - 1)
    v = disparity[ys, xs]
    if (~valid_of(v)).any() or float(np.abs(v - med).max()) > 2 * CLEAN_SPREAD * abs(med):
        return float("nan")
    return med
