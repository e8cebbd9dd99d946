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


def _residuals(t: np.ndarray, H: np.ndarray | None, d: np.ndarray, beta: np.ndarray) -> np.ndarray:
    r = d[None] - beta[:, :1]
    tmp = np.multiply(beta[:, 1:2], t[None])
    r -= tmp
    if H is not None:
        np.multiply(beta[:, 2:3], H, out=tmp)
        r -= tmp
    return r


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
    from measure.compiled import crease_candidates, row_scales  # loaded on first use: `import measure` stays fast
    # The one line is fitted with the candidates (a crease beyond the far end: a hinge column of zeros).
    t0s, b2, b1, s1, med1, parted = crease_candidates(t, d, float(length), float(quantum), floor, MIN_PIECE_PX, MIN_PIECE_SAMPLES,
                                                      CANDIDATES, DISAGREE_REL)
    if t0s.size == 0 or s1 <= floor:
        return None  # s1 at the floor: every s2 is floored there too, the crease cannot lower the scale (condition 1)
    # Condition 3 without its scale term: when no candidate's pieces part by more than a quantum and
    # DISAGREE_REL of its disparity at the crease, the best one's cannot, whatever the scales (most
    # straight profiles end here, without the second pass's residuals and medians).
    if not parted:
        return None
    s2, med2 = row_scales(t, d, t0s, b2, floor)
    k = int(np.argmin(s2))
    r2k = _residuals(t, np.maximum(t - t0s[k], 0.0)[None], d, b2[k : k + 1])[0]
    n_eff = n / correlation_inflation(r2k) ** 2
    if not n_eff * math.log(s1 * s1 / (s2[k] * s2[k])) > PENALTY * 2.0 * math.log(max(n_eff, 2.0)):
        return None
    inl = np.abs(r2k - med2[k]) <= 3.0 * s2[k]
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
    r1 = _residuals(t, None, d, b1[None, :2])[0]
    one = np.abs(r1 - med1) <= 3.0 * s2[k]
    apart = np.abs(r1 - r2k) > 3.0 * s2[k]
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
