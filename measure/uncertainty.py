"""One-sigma uncertainty of a measured distance (metres), and its calibration.

Terms, added in quadrature:

1. **Fit term** (robust and paper methods, fit "line"): the robust line's centroid and direction
   errors (Sigma_perp / n and Sigma_perp / sum(s_i²), with Sigma_perp the MCD scatter perpendicular
   to the line) propagated to the distance by central differences of the end-point construction
   (``line_fit_sigma``, 12 evaluations in one vectorised call). An end far outside the support, or a
   ray nearly parallel to the line, shows as a large uncertainty.
2. **Quantization term** (``quantization_sigma``): samples on one disparity level share one rounding
   error. With quantum q (``disparity_quantum``) and L levels in the support the distance moves by
   D Z / (fB) q / sqrt(12 L), damped by exp(-2 pi² s² / q²) for noise s before the rounding
   (``rounding_sigma``). For a constant-depth or plane exact fit this is the whole uncertainty; a
   gap's ends each have their own (``measure.gap``).
3. **Window ends** (basic, the paper's end point input, gap answers): the standard error of the median
   depth, Z²/(fB) 1.2533 * 1.4826 MAD(d) / sqrt(k) for k window disparities (floored at the
   quantization term), propagated through dD/dZ_i = r_i . (P_i - P_j) / D (``endpoint_depth_sigma``).
4. **Robust method extras**: the fit term inflated for residuals correlated along the segment
   (``correlation_inflation``), the click position (``click_sigma``: each end moved
   ``MeasureOptions.click_px`` along the segment on its own model), the model choice (``MODEL_SHARE``
   of the distance to the other model's answer) and the residual structure next to each end
   (``measure.surfaces``). Never zero (``MIN_RELATIVE_SIGMA``).

Calibration (``calibrated_sigma``, ``interval``): the reported one-sigma is ``SIGMA_SCALE`` model
sigmas and the 95 % interval ``INTERVAL_SCALE`` model sigmas either side, set on the dev half of the
Middlebury stress protocol (docs/decisions/uncertainty-calibration.md has the quantiles behind both).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from measure.robust_range import median


def disparity_quantum(disparities: np.ndarray) -> float:
    """Smallest positive step between distinct disparity values (px), capped at 1 px."""
    steps = _steps(disparities)
    return min(1.0, float(steps.min())) if steps.size else 1.0


def distinct_levels(disparities: np.ndarray) -> int:
    """Number of distinct disparity values."""
    return int(np.size(disparities) > 0) + int(_steps(disparities).size)


def _steps(disparities: np.ndarray) -> np.ndarray:
    """The positive steps between neighbouring distinct values (np.unique's, without its overhead)."""
    steps = np.diff(np.sort(np.asarray(disparities, dtype=np.float64).ravel()))
    return steps[steps > 0]


def rounding_sigma(quantum: float, levels: int, noise_px: float = 0.0) -> float:
    """Disparity error (px) that samples on ``levels`` independent levels of step ``quantum`` share
    through rounding: q / sqrt(12 L), damped for dithering noise.

    Noise of standard deviation s before rounding dithers it: the rounding error then varies
    from sample to sample (and is in the fit's residuals) instead of being shared; its shared
    part decays as exp(-2 pi² s² / q²) (the first Fourier term of the rounding error). ``noise_px``
    is the observed residual scatter, of which q²/12 is the rounding itself.
    """
    s2 = max(0.0, noise_px * noise_px - quantum * quantum / 12.0)
    shared = math.exp(-2.0 * math.pi**2 * s2 / (quantum * quantum)) if quantum > 0 else 0.0
    return quantum / math.sqrt(12.0 * max(1, levels)) * shared


def quantization_sigma(distance: float, mean_depth: float, fb: float, quantum: float, levels: int, noise_px: float = 0.0) -> float:
    """Distance error (m) from a common disparity rounding error of ``levels`` independent levels
    (``rounding_sigma``) on a segment at ``mean_depth`` (m): D Z / (fB) times that error."""
    return abs(distance) * mean_depth / fb * rounding_sigma(quantum, levels, noise_px)


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


def window_disparity_se(window_disparities: np.ndarray, quantum: float) -> float:
    """Standard error (px) of a window's median disparity (NaN for an empty window)."""
    d = np.asarray(window_disparities, dtype=np.float64)
    if d.size == 0:
        return math.nan
    mad = 1.4826 * median(np.abs(d - median(d)))
    return max(1.2533 * mad / math.sqrt(d.size), quantum / math.sqrt(12.0))


def depth_sigma(depth: float, fb: float, disparity_se: float) -> float:
    """Standard error (m) of a depth (m) from its disparity's standard error (px): Z² / (fB) times it."""
    if not math.isfinite(depth):
        return math.nan
    return depth * depth / fb * disparity_se


def endpoint_depth_sigma(p1: np.ndarray, p2: np.ndarray, sigma_z1: float, sigma_z2: float) -> float:
    """Distance error (m) from independent depth errors of two end points on their viewing rays."""
    diff = p1 - p2
    dist = float(np.linalg.norm(diff))
    if dist == 0:
        return math.nan
    g1 = float((p1 / p1[2]) @ diff) / dist
    g2 = float((p2 / p2[2]) @ -diff) / dist
    return math.sqrt((g1 * sigma_z1) ** 2 + (g2 * sigma_z2) ** 2)


# Empirical calibration (module docstring "Calibration"): the model's sigma times SIGMA_SCALE is the
# reported one-sigma; the 95 % interval is INTERVAL_SCALE model sigmas either side.
SIGMA_SCALE = 1.25
INTERVAL_SCALE = 3.9
MODEL_SHARE = 0.5  # share of the distance to the other model's answer counted as model-choice error
MIN_RELATIVE_SIGMA = 1e-4  # never sigma = 0: a tenth of a millimetre per metre at least


def correlation_inflation(residuals: np.ndarray) -> float:
    """Factor on a fit's standard errors for residuals correlated along the segment (stereo matching
    windows make neighbouring disparities share errors): sqrt((1 + rho) / (1 - rho)) for the lag-one
    autocorrelation rho of ``residuals`` (in segment order), rho clipped to [0, 0.9]."""
    r = np.asarray(residuals, dtype=np.float64)
    if r.size < 4:
        return 1.0
    from measure.compiled import lag_one_correlation  # loaded on first use: `import measure` stays fast

    rho = min(0.9, max(0.0, float(lag_one_correlation(np.ascontiguousarray(r)))))
    return math.sqrt((1.0 + rho) / (1.0 - rho))


def click_sigma(ray_at: Callable[[float, float], np.ndarray], xy1, xy2, d_end: np.ndarray, slope: np.ndarray, fb: float, doffs: float, distance: float,
                click_px: float) -> float:
    """Distance error (m) from clicks off by ``click_px`` (px, one sigma, the caller's
    ``MeasureOptions.click_px``) along the segment: each end moved one pixel outwards on its own model
    (disparity d_end + slope per px), the change in distance propagated and scaled by ``click_px``."""
    if click_px == 0:
        return 0.0
    x1, y1 = xy1
    x2, y2 = xy2
    n = math.hypot(x2 - x1, y2 - y1)
    ux, uy = (x2 - x1) / n, (y2 - y1) / n
    p1 = ray_at(x1, y1) * fb / (d_end[0] + doffs)
    p2 = ray_at(x2, y2) * fb / (d_end[1] + doffs)
    da, db = d_end[0] - slope[0] + doffs, d_end[1] + slope[1] + doffs
    if da <= 0 or db <= 0:
        return math.inf
    a = ray_at(x1 - ux, y1 - uy) * fb / da
    b = ray_at(x2 + ux, y2 + uy) * fb / db
    g1 = float(np.linalg.norm(p2 - a)) - distance
    g2 = float(np.linalg.norm(b - p1)) - distance
    return click_px * math.hypot(g1, g2)


def calibrated_sigma(model_sigma: float, distance: float, scale: float = SIGMA_SCALE) -> float:
    """Reported one-sigma (m): the model's times ``scale`` (SIGMA_SCALE unless a model has a calibration
    of its own), at least MIN_RELATIVE_SIGMA of the distance."""
    s = scale * model_sigma if math.isfinite(model_sigma) else math.inf
    return max(s, MIN_RELATIVE_SIGMA * abs(distance))


def interval(distance: float, sigma: float) -> tuple[float, float]:
    """95 % interval (m) around ``distance`` for a reported one-sigma ``sigma`` (never below zero)."""
    half = INTERVAL_SCALE / SIGMA_SCALE * sigma
    return (max(0.0, distance - half), distance + half)
