"""The robust method's model: disparity as a robust straight line along the segment, d(t) = alpha + beta t.

Along one image line the points of a straight 3D segment have disparity exactly affine in the pixel
position t, so the robust 3D line met by the clicked pixels' viewing rays is d(t) at the clicks; t is
exact, d carries the noise (docs/decisions/viewing-ray-ends.md).

Steps (``fit_disparity_line``):

1. FAST-MCD (p = 2) on (t, d) with ``starts_for(2, failure=1e-6)`` random starts, the 5 best per
   subsample and two C-steps on the full data: a robust start (an exact fit is only a start here).
2. Tukey-bisquare IRLS regression of d on t with the scale fixed at max(1.4826 MAD of the start's
   support residuals, q/sqrt(12)) (q the disparity quantum: quantized data do not collapse onto one
   level).
3. ``alt_start`` (the robust method passes the line through its click windows' medians): unless it
   lies within the first line's tight band at both ends, the IRLS from it runs too, at the scale of
   its own better half, then at the tighter of the two scales; that line wins when both its least
   trimmed squares (h = support_fraction n) are smaller and it supports more samples within the tight
   band.

The estimator's settings and the second start were measured against converged R&VD FAST-MCD:
docs/decisions/line-estimator.md. Units: t and d in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.mcd import McdResult, fast_mcd, starts_for
from measure.robust_range import median

# See the module docstring: FAST-MCD supplies the start, the IRLS the answer.
_STARTS = starts_for(2, failure=1e-6)
_BEST_PER_SUBSAMPLE = 5
_FULL_DATA_STEPS = 2


@dataclass(frozen=True)
class DisparityLine:
    """A robust line d(t) = alpha + beta t of disparity d (px) along a segment at position t (px).

    Made by :func:`fit_disparity_line`.

    Args:
        alpha: disparity at t = 0 (float, px).
        beta: slope of the disparity along the segment (float, px of disparity per px of t).
        sigma_d: per-sample disparity noise of the support: RMS residual, at least q/sqrt(12) (float, px).
        param_cov: (2, 2) float64 covariance of (alpha, beta) (px², px²/px, px²/px²).
        support: (n,) bool array, True for the samples with non-zero bisquare weight.
        exact_start: the FAST-MCD start was an exact fit (e.g. half the samples on one level) (bool).

    Returns:
        A frozen line; :meth:`at` evaluates it, :meth:`cov_at` gives the covariance of two of its values.

    Examples:
        >>> from measure.dline import DisparityLine
        >>> line = DisparityLine(10.0, 0.5, 0.1, np.eye(2) * 0.01, np.ones(4, bool), False)
        >>> print(line.at(4.0), line.cov_at(0.0, 1.0).round(3).tolist())
        12.0 [[0.01, 0.01], [0.01, 0.02]]
    """

    alpha: float
    beta: float
    sigma_d: float
    param_cov: np.ndarray
    support: np.ndarray
    exact_start: bool

    def at(self, t: float | np.ndarray) -> float | np.ndarray:
        """Fitted disparity (px) at position ``t`` (px; a float or an array of any shape)."""
        return self.alpha + self.beta * t

    def cov_at(self, t1: float, t2: float) -> np.ndarray:
        """2x2 covariance of the fitted disparities at t1 and t2.

        Args:
            t1: first position along the segment (float, px).
            t2: second position (float, px).

        Returns:
            (2, 2) float64 covariance of (d(t1), d(t2)) (px²).
        """
        a = np.array([[1.0, t1], [1.0, t2]])
        return a @ self.param_cov @ a.T


def mcd_line(res: McdResult) -> tuple[float, float] | None:
    """Intercept and slope of the line y = a + b t that a FAST-MCD result on (t, y) describes:
    its exact-fit line, else its first principal axis through the robust location (a flat
    principal axis for a vertical one). None when the exact fit is no line y(t): all support
    points at one (t, y), or a vertical line."""
    if res.exact_fit:
        if res.fit_kind == "hyperplane" and abs(res.plane[1]) > 1e-12:
            a1, a2, c = res.plane
            return -c / a2, -a1 / a2
        return None
    v = res.principal_axis()
    slope = float(v[1] / v[0]) if abs(v[0]) > 1e-12 else 0.0
    return float(res.location[1] - slope * res.location[0]), slope


def fit_disparity_line(t: np.ndarray, d: np.ndarray, support_fraction: float, seed: int, quantum: float, iterations: int = 50,
                       alt_start: tuple[float, float] | None = None) -> DisparityLine:
    """Robust d = alpha + beta t of samples at positions ``t`` (px) with disparities ``d`` (px).

    FAST-MCD on (t, d) gives the start, Tukey-bisquare IRLS with a fixed scale the answer (module docstring).

    Args:
        t: (n,) positions of the samples along the segment (float, px), n >= 3.
        d: (n,) disparities of the samples (float, px), finite.
        support_fraction: fraction h/n of the samples FAST-MCD keeps (float in [0.5, 1.0]).
        seed: seed of FAST-MCD's random starts (int >= 0).
        quantum: disparity quantum q of the sensor (float, px, e.g. 1/16; 0 for continuous disparity);
            the noise scale is at least q/sqrt(12) so quantized data do not collapse onto one level.
        iterations: most IRLS iterations (int); it stops earlier once the line moves by < 1e-4 of the scale.
        alt_start: a second (alpha, beta) start (px, px per px), e.g. through the click windows' medians;
            the converged line with the smaller least trimmed squares wins.

    Returns:
        The :class:`DisparityLine`, its ``support`` of shape (n,).

    Examples:
        >>> import numpy as np
        >>> from measure.dline import fit_disparity_line
        >>> t = np.arange(40.0)
        >>> d = 10.0 + 0.05 * t
        >>> d[::10] += 3.0  # four wrong matches
        >>> line = fit_disparity_line(t, d, support_fraction=0.5, seed=0, quantum=1 / 16)
        >>> print(round(line.alpha, 3), round(line.beta, 4), int(line.support.sum()), line.exact_start)
        10.0 0.05 36 True
    """
    t = np.asarray(t, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    res = fast_mcd(
        np.column_stack((t, d)), support_fraction=support_fraction, seed=seed,
        n_starts=_STARTS, n_best=_BEST_PER_SUBSAMPLE, max_iter=_FULL_DATA_STEPS,
    )
    line = mcd_line(res)
    # All support samples at one (t, d), or a vertical line: start flat.
    alpha, beta = line if line is not None else (median(d[res.support]), 0.0)
    has_alt = alt_start is not None and all(map(math.isfinite, alt_start))
    a_alt, b_alt = alt_start if has_alt else (0.0, 0.0)
    h = max(2, int(math.ceil(support_fraction * t.size)))
    from measure.compiled import robust_line  # loaded on first use: `import measure` stays fast

    # Steps 2 and 3 (the second start's IRLS at the scale of its own better half, then at the tighter of
    # the two scales: at or past half wrong matches FAST-MCD's half-sample can hold outliers that tilt
    # it; a wide scale takes wrong matches into the fit) in one compiled call.
    alpha, beta, _, support, sigma, ns, st, stt = robust_line(
        np.ascontiguousarray(t), np.ascontiguousarray(d), res.support, float(alpha), float(beta), quantum / math.sqrt(12.0),
        has_alt, float(a_alt), float(b_alt), h, iterations)
    det = ns * stt - st * st
    # (X^T X)^-1 of the 2x2 normal equations, closed form.
    cov = sigma * sigma / det * np.array([[stt, -st], [-st, ns]]) if det > 0 else np.full((2, 2), np.inf)
    return DisparityLine(alpha, beta, sigma, cov, support, bool(res.exact_fit))
