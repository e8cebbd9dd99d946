"""One-sigma uncertainty of a measured distance (metres).

The model has two parts, added in quadrature:

1. **Fit term** (robust and paper methods, fit "line"). The robust line T + s v is estimated
   from the n support points whose scatter perpendicular to v, Sigma_perp = (I - v v')
   S (I - v v') with S the consistency-corrected MCD covariance, is the disparity noise
   propagated through Z = fB/d (it is almost all along the viewing rays) plus any surface
   roughness. For a total-least-squares line the centroid error has covariance
   Sigma_perp / n and the direction error Sigma_perp / sum(s_i²) (s_i the support points'
   positions along the line), independent of each other. Both are propagated to the
   distance by central differences of the end-point construction along the principal
   directions of Sigma_perp (12 evaluations, one vectorised call): the extrapolation to
   an end point far outside the support, or a ray nearly parallel to the line, shows up
   as a large uncertainty, which is what an end point without depth deserves.
2. **Quantization term.** Samples on one disparity level share one rounding error, which no
   fit averages away. With disparity quantum q (the smallest step between the valid
   samples' disparity values, at most 1 px) a common disparity offset of q/sqrt(12) per
   level, averaged over the L distinct levels in the support, changes every depth by
   Z²/(fB) q / sqrt(12 L) and so the distance by D Z / (fB) q / sqrt(12 L) (relative
   error of depth = relative error of scale). Noise before the rounding dithers it (then
   it is part of the residuals, not shared): the term is scaled by exp(-2 pi² s² / q²)
   with s the noise beyond the rounding's own q²/12. For a constant-depth or plane exact
   fit this is the whole uncertainty.

Window-based end points (basic, the paper's end point input, gap answers) carry the
standard error of their median depth: Z²/(fB) times 1.2533 * 1.4826 MAD(d) / sqrt(k) for
k window disparities (floored at the quantization term), propagated through dD/dZ_i =
r_i . (P_i - P_j) / D.

Validated in tests/test_measure_uncertainty.py: within a factor 1.5 of the standard
deviation of 200 noisy repeats.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .robust_range import median


def disparity_quantum(disparities: np.ndarray) -> float:
    """Smallest positive step between distinct disparity values (px), capped at 1 px."""
    u = np.unique(np.asarray(disparities, dtype=np.float64))
    if u.size < 2:
        return 1.0
    step = float(np.diff(u).min())
    return min(1.0, step)


def quantization_sigma(distance: float, mean_depth: float, fb: float, quantum: float, levels: int, noise_px: float = 0.0) -> float:
    """Distance error (m) from a common disparity rounding error of ``levels`` independent levels.

    Noise of standard deviation s before rounding dithers it: the rounding error then varies
    from sample to sample (and is in the fit's residuals) instead of being shared; its shared
    part decays as exp(-2 pi² s² / q²) (the first Fourier term of the rounding error). ``noise_px``
    is the observed residual scatter, of which q²/12 is the rounding itself.
    """
    s2 = max(0.0, noise_px * noise_px - quantum * quantum / 12.0)
    shared = math.exp(-2.0 * math.pi**2 * s2 / (quantum * quantum)) if quantum > 0 else 0.0
    return abs(distance) * mean_depth / fb * quantum / math.sqrt(12.0 * max(1, levels)) * shared


def line_fit_sigma(
    endpoints: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    point: np.ndarray,
    direction: np.ndarray,
    scatter: np.ndarray,
    support_points: np.ndarray,
) -> float:
    """Fit term of the module docstring: propagate the line's centroid and direction errors.

    ``endpoints(T, v)`` maps batches (k x 3) of line points and unit directions to the two
    end points (each k x 3).
    """
    v = direction / np.linalg.norm(direction)
    perp = np.eye(3) - np.outer(v, v)
    sig = perp @ scatter @ perp
    vals, vecs = np.linalg.eigh(sig)
    vals = np.clip(vals, 0.0, None)
    n = len(support_points)
    s2 = float((((support_points - point) @ v) ** 2).sum())
    if n < 2 or s2 <= 0:
        return math.nan
    steps_t = (np.sqrt(vals / n) * vecs).T  # 3 x 3: one perturbation per row
    steps_v = (np.sqrt(vals / s2) * vecs).T
    zeros = np.zeros_like(steps_t)
    t = np.concatenate([point + steps_t, point - steps_t, point + zeros, point + zeros])
    dv = np.concatenate([zeros, zeros, steps_v, -steps_v])
    vv = v + dv
    vv /= np.linalg.norm(vv, axis=1, keepdims=True)
    p1, p2 = endpoints(t, vv)
    d = np.linalg.norm(p2 - p1, axis=1).reshape(4, 3)
    var = (((d[0] - d[1]) / 2) ** 2).sum() + (((d[2] - d[3]) / 2) ** 2).sum()
    return float(math.sqrt(var)) if np.isfinite(var) else math.inf


def window_depth_sigma(window_disparities: np.ndarray, depth: float, fb: float, quantum: float) -> float:
    """Standard error (m) of the depth from a window's median disparity."""
    d = np.asarray(window_disparities, dtype=np.float64)
    if d.size == 0 or not math.isfinite(depth):
        return math.nan
    mad = 1.4826 * median(np.abs(d - median(d)))
    sd = max(1.2533 * mad / math.sqrt(d.size), quantum / math.sqrt(12.0))
    return depth * depth / fb * sd


def endpoint_depth_sigma(p1: np.ndarray, p2: np.ndarray, sigma_z1: float, sigma_z2: float) -> float:
    """Distance error (m) from independent depth errors of two end points on their viewing rays."""
    diff = p1 - p2
    dist = float(np.linalg.norm(diff))
    if dist == 0:
        return math.nan
    g1 = float((p1 / p1[2]) @ diff) / dist
    g2 = float((p2 / p2[2]) @ -diff) / dist
    return math.sqrt((g1 * sigma_z1) ** 2 + (g2 * sigma_z2) ** 2)
