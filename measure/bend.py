"""A bent segment: is the disparity profile along the segment two straight pieces meeting at a crease?

A wall and the floor in front of it (or a standing board and the floor) are two planes; on each, disparity
is linear along the segment, so the profile is two lines that meet at the seam. When the segment's one
robust line has already been kept (``measure.surfaces`` found no surface of its own at either end),
``hinge_ends`` compares that model with the continuous two-piece line

    d(t) = a + b t + c max(t - t0, 0)                                             (docs/method.md, "bent segments")

over crease positions t0 at least ``MIN_PIECE_PX`` from both ends (one least-squares fit per candidate, all
at once, the one line among them; then again on the samples within 3 robust sigmas of the first fit).
The crease is kept when

1. it is worth its two extra parameters: n log(s1² / s2²) > ``PENALTY`` · 2 log n (BIC, with the robust
   scales s = 1.4826 MAD of the residuals, floored at the rounding q / sqrt(12)), n counted as
   independent samples (n divided by the residuals' correlation inflation squared);
2. it is two surfaces: at least ``MIN_INLIERS`` of the samples lie within 3 s of it, and s is at most
   ``LOCAL_ROUGHNESS`` times the one line's noise on its support;
3. the bend is large: the two pieces' lines, extended to the far end of the shorter piece, part by
   more than ``BEND_SIGMAS`` · s, one disparity quantum and ``DISAGREE_REL`` of the disparity at the
   crease (the offset at which ``measure.surfaces`` gives an end a surface of its own);
4. the samples follow it: where the two-piece line and the one line part by more than 3 s, more samples
   lie within 3 s of the two-piece line than of the one line;
5. no extrapolation: each end's value lies within its piece's inlying samples' range (and a quantum).

Units: t in px along the segment from p1, disparities in px. Why and the measurement:
docs/decisions/bent-segments.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.surfaces import DISAGREE_REL, LOCAL_ROUGHNESS, EndModels
from measure.uncertainty import correlation_inflation

MIN_PIECE_PX = 15.0  # each piece at least this long (the shortest surface of measure.surfaces)
MIN_PIECE_SAMPLES = 10
PENALTY = 1.0  # BIC's: each extra parameter costs log n
BEND_SIGMAS = 4.0
CANDIDATES = 48
MIN_INLIERS = 0.8  # share of the samples within 3 robust sigmas of the two-piece line: two surfaces, not scattered wrong matches


@dataclass(frozen=True)
class Hinge:
    """The two-piece line: crease position (px), the value (px) and slope (px / px, along t) at each end."""

    t0: float
    d_end: tuple[float, float]
    slope: tuple[float, float]  # d(d)/dt at p1 and at p2
    scale: float  # robust residual scale (px)


def _scale(r: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Each row's robust scale 1.4826 MAD (floored) and its median, ``r`` (K, n), from one sort a row.

    On a sorted row the distances |r - median| fall, then rise, so their j-th smallest is the smallest,
    over windows of j + 1 neighbours, of the larger distance at the window's two ends: the MAD needs no
    second selection (the same numbers as a partition of |r - median|)."""
    n = r.shape[1]
    lo, hi = (n - 1) // 2, n // 2
    s = np.sort(r, axis=1)
    med = 0.5 * (s[:, lo] + s[:, hi])
    below = med[:, None] - s[:, : n - lo]  # med - s[i], the window's left end
    above = s[:, lo:] - med[:, None]  # s[i + lo] - med, its right end
    q_hi = np.maximum(below[:, : n - hi], above[:, hi - lo :]).min(axis=1)
    np.maximum(below, above, out=below)
    return np.maximum(1.4826 * (0.5 * (below.min(axis=1) + q_hi)), floor), med


def _fit(terms: tuple[np.ndarray, np.ndarray], H: np.ndarray, w: np.ndarray | None) -> np.ndarray:
    """Weighted least squares of d on the columns 1, t and H (the hinge column of each candidate):
    weights ``w`` (K, n; None: all one) -> coefficients (K, 3), from the normal equations' sums.
    ``terms`` holds each sample's 1, t, t², d, t d (n, 5) and 1, t, d (n, 3): one product with the
    weights gives the line's five sums (as measure.dline's IRLS), one more with the weighted hinge
    column the hinge's."""
    terms, hterms = terms
    k = H.shape[0]
    sums = np.broadcast_to(terms.sum(axis=0), (k, 5)) if w is None else w @ terms
    wh = H if w is None else w * H
    hs = wh @ hterms
    A = np.empty((k, 3, 3))
    A[:, 0, 0], A[:, 0, 1], A[:, 1, 1] = sums[:, 0], sums[:, 1], sums[:, 2]
    A[:, 0, 2], A[:, 1, 2], A[:, 2, 2] = hs[:, 0], hs[:, 1], np.einsum("kn,kn->k", wh, H)
    A[:, 1, 0], A[:, 2, 0], A[:, 2, 1] = A[:, 0, 1], A[:, 0, 2], A[:, 1, 2]
    A += 1e-9 * np.eye(3)
    y = np.stack([sums[:, 3], sums[:, 4], hs[:, 2]], axis=1)
    return np.linalg.solve(A, y[..., None])[..., 0]


def _residuals(t: np.ndarray, H: np.ndarray | None, d: np.ndarray, beta: np.ndarray) -> np.ndarray:
    r = d[None] - beta[:, :1]
    tmp = np.multiply(beta[:, 1:2], t[None])
    r -= tmp
    if H is not None:
        np.multiply(beta[:, 2:3], H, out=tmp)
        r -= tmp
    return r


def _trimmed_fit(t: np.ndarray, H: np.ndarray, d: np.ndarray, floor: float, terms: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Least squares, then least squares on the samples within 3 robust sigmas of it: the second
    pass's coefficients. ``terms``: as :func:`_fit`'s."""
    beta = _fit(terms, H, None)
    r = _residuals(t, H, d, beta)
    s, med = _scale(r, floor)
    r -= med[:, None]
    np.abs(r, out=r)
    return _fit(terms, H, (r <= 3.0 * s[:, None]).astype(np.float64))


def hinge_ends(t: np.ndarray, d: np.ndarray, length: float, quantum: float, noise: float) -> Hinge | None:
    """The crease model of the module docstring for samples ``d`` (px) at ``t`` (px along the segment of
    ``length`` px; ``noise``: the one line's residual scale on its support, px), or None when one line
    is as good."""
    t = np.asarray(t, np.float64)
    d = np.asarray(d, np.float64)
    n = t.size
    if length < 2 * MIN_PIECE_PX or n < 2 * MIN_PIECE_SAMPLES:
        return None
    floor = quantum / math.sqrt(12.0)
    t0s = np.linspace(MIN_PIECE_PX, length - MIN_PIECE_PX, CANDIDATES)
    left = np.searchsorted(np.sort(t), t0s)  # samples before each crease
    t0s = t0s[(left >= MIN_PIECE_SAMPLES) & (n - left >= MIN_PIECE_SAMPLES)]
    if t0s.size == 0:
        return None
    terms = np.stack([np.ones_like(t), t, t * t, d, t * d], axis=1)
    terms = (terms, terms[:, [0, 1, 3]])
    # Row 0 is the one line: a hinge column of zeros (its coefficient stays 0), fitted with the candidates.
    H = np.maximum(t[None] - np.concatenate([[np.inf], t0s])[:, None], 0.0)
    b2 = _trimmed_fit(t, H, d, floor, terms)
    r1 = _residuals(t, None, d, b2[:1, :2])[0]
    s1_row, med1 = _scale(r1[None], floor)
    s1 = float(s1_row[0])
    if s1 <= floor:
        return None  # every s2 is floored there too: the crease cannot lower the scale (condition 1)
    H, b2 = H[1:], b2[1:]
    # Condition 3 without its scale term: when no candidate's pieces part by more than a quantum and
    # DISAGREE_REL of its disparity at the crease, the best one's cannot, whatever the scales (most
    # straight profiles end here, without the second pass's residuals and medians).
    part = np.abs(b2[:, 2]) * np.minimum(t0s, length - t0s)
    if not (part > np.maximum(quantum, DISAGREE_REL * np.abs(b2[:, 0] + b2[:, 1] * t0s))).any():
        return None
    r2 = _residuals(t, H, d, b2)
    s2, med2 = _scale(r2, floor)
    k = int(np.argmin(s2))
    n_eff = n / correlation_inflation(r2[k]) ** 2
    if not n_eff * math.log(s1 * s1 / (s2[k] * s2[k])) > PENALTY * 2.0 * math.log(max(n_eff, 2.0)):
        return None
    inl = np.abs(r2[k] - med2[k]) <= 3.0 * s2[k]
    if float(np.mean(inl)) < MIN_INLIERS or s2[k] > LOCAL_ROUGHNESS * max(noise, floor):
        return None
    a, b, c = (float(v) for v in b2[k])
    t0 = float(t0s[k])
    shorter = min(t0, length - t0)
    at_crease = abs(a + b * t0)
    if not abs(c) * shorter > max(BEND_SIGMAS * float(s2[k]), quantum, DISAGREE_REL * at_crease):
        return None
    # Where the two models part, the samples must follow the crease: a step to scattered wrong matches past an
    # object's edge lowers the (MAD) scale by threading a steep piece through a few of them (condition 4).
    one = np.abs(r1 - med1[0]) <= 3.0 * s2[k]
    apart = np.abs(r1 - r2[k]) > 3.0 * s2[k]
    if not (inl & apart).sum() > (one & apart).sum():
        return None
    ends = (a, a + b * length + c * (length - t0))
    # No extrapolation: each end's value lies within the range of its piece's inlying samples (and a quantum).
    for e, piece in ((0, inl & (t < t0)), (1, inl & (t >= t0))):
        if piece.sum() < MIN_PIECE_SAMPLES or not (d[piece].min() - quantum <= ends[e] <= d[piece].max() + quantum):
            return None
    return Hinge(t0, ends, (b, b + c), float(s2[k]))


def bent_end_models(t: np.ndarray, d: np.ndarray, length: float, quantum: float, noise: float, ends: EndModels) -> EndModels:
    """``ends`` unchanged unless no end has a surface of its own and the profile is bent (``hinge_ends``):
    then each end takes its own piece's line at the click, with the variance of a least-squares line at
    the end of its samples (about 4 s² / k for k samples of the piece) and independent errors."""
    if ends.several:
        return ends
    h = hinge_ends(t, d, length, quantum, noise)
    if h is None:
        return ends
    k1 = max(1, int((np.asarray(t) < h.t0).sum()))
    k2 = max(1, int(np.asarray(t).size) - k1)
    cov = np.diag([4.0 * h.scale**2 / k1, 4.0 * h.scale**2 / k2])
    return EndModels(np.array(h.d_end), np.array(h.slope), cov, (True, True), (0.0, 0.0), ends.pieces)
