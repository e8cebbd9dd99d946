"""The disparity line on few quantized levels: interval-censored (ordered-probit) regression.

Model: a sensor rounds disparity to a quantum q, so sample i reports level d_i when
alpha + beta t_i + e_i lies in [d_i - q/2, d_i + q/2), e_i normal with sd s (the noise before
rounding). Its likelihood is Phi(a_i) - Phi(b_i), with a_i, b_i the interval's ends minus the line,
over s. With two levels the data identify only beta / s and the crossing position, so s is a
nuisance, marginalised. Steps:

1. For each s on a grid over (0, q]: the maximum-likelihood line (Newton, log-concave), tempered by
   the squared correlation inflation (``measure.uncertainty``: n neighbouring stereo samples count as
   n / inflation²).
2. The Laplace approximation of the likelihood's integral over (alpha, beta) with flat priors, a
   flat prior on s.
3. The answer: the posterior mean line and the mixture's covariance (each s's inverse information
   plus the spread of the lines between s values).

Used on the robust line's support when its samples lie on 2 to ``MAX_LEVELS`` neighbouring levels
(``few_levels``); ``measure.robust`` takes this line only where it is flatter than the least-squares
one, else keeps least squares with this posterior's mean squared error as its covariance.
Why: least squares fits a two-level staircase's step, not the line under it
(docs/decisions/censored-line.md has the measurement). Units: t in px along the segment, d and q in
px of disparity.
"""

from __future__ import annotations

import numpy as np
from scipy.special import log_ndtr

MAX_LEVELS = 3  # neighbouring levels; over more, least squares already follows the half-level crossings
_GRID = 12  # values of the noise sd s on (0, q], uniform (a flat prior on s)
_NEWTON = 10  # most Newton steps per s (log-concave likelihood; from the least-squares line)
_LOG_2PI = float(np.log(2.0 * np.pi))


def _log_interval(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log(Phi(a) - Phi(b)) for a > b, stable in both tails (the upper tail by symmetry)."""
    flip = b > 0
    hi = np.where(flip, -b, a)
    lo = np.where(flip, -a, b)
    lh, ll = log_ndtr(hi), log_ndtr(lo)
    return lh + np.log1p(-np.exp(np.minimum(ll - lh, -1e-300)))


def _derivatives(mu: np.ndarray, lo_edge: np.ndarray, hi_edge: np.ndarray, inv_s: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sample and noise value, for lines ``mu`` (J, n) and noise 1 / ``inv_s`` (J, 1): log P of the
    sample's level interval, and its first and second derivatives in mu (the second capped below zero:
    the likelihood is log-concave)."""
    a, b = (hi_edge - mu) * inv_s, (lo_edge - mu) * inv_s
    logp = _log_interval(a, b)
    # phi(x) / P for both ends, in logs (P underflows far outside a sample's interval).
    ra = np.exp(-0.5 * a * a - 0.5 * _LOG_2PI - logp)
    rb = np.exp(-0.5 * b * b - 0.5 * _LOG_2PI - logp)
    g = (rb - ra) * inv_s
    h = np.minimum((b * rb - a * ra) * inv_s * inv_s - g * g, -1e-12)
    return logp, g, h


def few_levels(d: np.ndarray, quantum: float) -> bool:
    """Disparities ``d`` (px) on 2 to MAX_LEVELS neighbouring multiples of ``quantum`` (px): the
    staircase case. Levels further apart are not rounding of one line (a wrong match, another surface)."""
    if not quantum > 0 or np.size(d) == 0:
        return False
    r = np.round(np.asarray(d, dtype=np.float64) / quantum)
    return 1 <= float(r.max() - r.min()) <= MAX_LEVELS - 1


def censored_line(t: np.ndarray, d: np.ndarray, quantum: float, inflation: float) -> tuple[float, float, np.ndarray] | None:
    """Posterior mean line d(t) = alpha + beta t of quantized samples (module docstring).

    Args:
        t: (n,) positions along the segment of the line's supported samples (float, px).
        d: (n,) their reported disparities (float, px), multiples of ``quantum`` up to an offset.
        quantum: the disparity quantum q (px, > 0).
        inflation: correlation inflation of the residuals (>= 1): n samples count as n / inflation².

    Returns:
        (alpha, beta, cov) with cov the (2, 2) covariance of (alpha, beta) before correlation
        inflation (px², px²/px, px²/px²), or None when the samples span fewer than two levels or more
        than ``MAX_LEVELS``, or the fit fails (no noise value's Newton run settles).

    Examples:
        >>> import numpy as np
        >>> t = np.arange(100.0)  # true line 8.3 + 0.004 t: 0.40 px over the span, levels 8 and 9
        >>> d = np.round(8.3 + 0.004 * t + 0.15 * np.random.default_rng(0).standard_normal(100))
        >>> alpha, beta, cov = censored_line(t, d, 1.0, 1.0)
        >>> print(round(alpha, 2), round(beta * 99, 2), round(np.polyfit(t, d, 1)[0] * 99, 2))  # vs least squares
        8.2 0.61 0.9
    """
    t = np.asarray(t, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if t.size < 3 or not few_levels(d, quantum):
        return None
    if not float(np.abs(d).max()) * 1e-9 < quantum:
        return None  # a quantum lost in the values' rounding: the levels' intervals have no width
    # Centred, unit-span positions keep the 2x2 systems well conditioned.
    t0 = float(t.mean())
    half = max(0.5 * float(np.ptp(t)), 1.0)
    u = (t - t0) / half
    s = quantum * (np.arange(_GRID) + 0.5) / _GRID  # (J,)
    # Every Newton run starts from the samples' own least-squares line: inside their levels, whatever
    # line the caller had (the likelihood is log-concave, so the start only decides how soon it settles).
    uu = float((u * u).sum())
    alpha = np.full(_GRID, float(d.mean()))
    beta = np.full(_GRID, float((u * (d - d.mean())).sum()) / uu if uu > 0 else 0.0)
    hi_edge, lo_edge = d + 0.5 * quantum, d - 0.5 * quantum
    inv_s = (1.0 / s)[:, None]
    converged = np.zeros(_GRID, dtype=bool)
    for _ in range(_NEWTON):
        _, g, h = _derivatives(alpha[:, None] + beta[:, None] * u, lo_edge, hi_edge, inv_s)
        g0, g1 = g.sum(1), (g * u).sum(1)
        h00, h01, h11 = h.sum(1), (h * u).sum(1), (h * u * u).sum(1)
        det = h00 * h11 - h01 * h01
        ok = det > 0
        step_a = np.where(ok, (h11 * g0 - h01 * g1) / np.where(ok, det, 1.0), 0.0)
        step_b = np.where(ok, (h00 * g1 - h01 * g0) / np.where(ok, det, 1.0), 0.0)
        # Newton on a concave function: x - H^-1 g; damped to a level per step.
        step_a = np.clip(step_a, -quantum, quantum)
        step_b = np.clip(step_b, -quantum, quantum)
        alpha = alpha - step_a
        beta = beta - step_b
        # Converged when the line moves by less than 1e-3 of a level anywhere on the span.
        converged = np.abs(step_a) + np.abs(step_b) < 1e-3 * quantum
        if converged.all():
            break
    logp, _, h = _derivatives(alpha[:, None] + beta[:, None] * u, lo_edge, hi_edge, inv_s)
    k = max(1.0, inflation) ** 2
    info00, info01, info11 = -h.sum(1) / k, -(h * u).sum(1) / k, -(h * u * u).sum(1) / k
    det = info00 * info11 - info01 * info01
    loglik = logp.sum(1) / k
    # A noise value whose Newton run has not settled within _NEWTON damped steps has no maximum to
    # approximate around.
    good = converged & np.isfinite(loglik) & (det > 0) & np.isfinite(alpha) & np.isfinite(beta)
    if not good.any():
        return None
    # Laplace: the integral over (alpha, beta) of the tempered likelihood is exp(loglik) 2 pi / sqrt(det).
    logw = np.where(good, loglik - 0.5 * np.log(np.where(good, det, 1.0)), -np.inf)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    theta = np.stack([alpha, beta], axis=1)  # (J, 2) in centred, unit-span coordinates
    theta = np.where(good[:, None], theta, 0.0)
    mean = w @ theta
    inv = np.stack([np.stack([info11, -info01], 1), np.stack([-info01, info00], 1)], 1) / np.where(good, det, 1.0)[:, None, None]
    inv = np.where(good[:, None, None], inv, 0.0)
    dev = theta - mean
    # Mixture covariance, without the tempering: measure.robust inflates the line's errors itself.
    cov_u = (w[:, None, None] * (inv / k + dev[:, :, None] * dev[:, None, :] / k)).sum(0)
    # Back to alpha + beta t: alpha = a_u - b_u t0 / half, beta = b_u / half.
    jac = np.array([[1.0, -t0 / half], [0.0, 1.0 / half]])
    cov = jac @ cov_u @ jac.T
    beta_t = float(mean[1] / half)
    return float(mean[0] - beta_t * t0), beta_t, cov
