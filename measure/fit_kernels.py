"""The robust line's and FAST-MCD's compiled loops (numba) beside ``measure.kernels``: the Tukey IRLS of
the disparity line (``bisquare_line``), FAST-MCD's consistency correction and reweighting
(``mcd_finish``) and the subset masks of a C-step with few starts (``few_starts_masks``).

Each does numpy's element-wise operations; sums over the samples are added in sample order, where a
BLAS product adds them in another, so their last bits can differ from the numpy formulation they
replaced (answers within 5e-13 relative; no verdict, fit or gap changed: docs/decisions/core-speed.md).
The C-step's distances are summed with fused multiply-adds in OpenBLAS's order: the same bits, so the
same masks. Compiled on first use and cached on disk (numba ``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from measure.kernels import _ends, _select, start_coefficients
from measure.robust_range import TUKEY_C


@njit(cache=True, nogil=True, error_model="numpy")
def bisquare_line(t: np.ndarray, d: np.ndarray, alpha: float, beta: float, scale: float, iterations: int) -> tuple[float, float, np.ndarray]:
    """Tukey-bisquare IRLS of d = alpha + beta t from a start at a fixed ``scale`` (px) (``measure.dline``):
    per iteration the weights max(1 - u², 0)² of u = r / (``TUKEY_C`` scale), the five weighted sums of
    1, t, t², d and t d, the 2x2 normal equations in closed form; it stops when the line moves by less
    than 1e-4 of the scale anywhere on the segment, or when the weights leave no line (det <= 0).
    Returns the line and its residuals. Element by element numpy's operations; the sums are added in
    sample order (a BLAS product adds them in another: the last bits can differ)."""
    n = t.size
    r = np.empty(n)
    for i in range(n):
        r[i] = d[i] - (alpha + beta * t[i])
    lo, hi = t[0], t[0]
    for i in range(1, n):
        lo = min(lo, t[i])
        hi = max(hi, t[i])
    span = (hi - lo) + 1.0
    inv_cs = 1.0 / (TUKEY_C * scale)
    tol = 1e-4 * scale
    for _ in range(iterations):
        sw = swt = swtt = swd = swtd = 0.0
        for i in range(n):
            u = r[i] * inv_cs
            w = 1.0 - u * u
            if w > 0.0:
                w *= w
                ti = t[i]
                sw += w
                swt += ti * w
                swtt += (ti * ti) * w
                swd += d[i] * w
                swtd += (ti * d[i]) * w
        det = sw * swtt - swt * swt
        if det <= 0:
            break
        a_new = (swtt * swd - swt * swtd) / det
        b_new = (sw * swtd - swt * swd) / det
        done = abs(a_new - alpha) + abs(b_new - beta) * span < tol
        alpha, beta = a_new, b_new
        for i in range(n):
            r[i] = d[i] - (t[i] * beta + alpha)
        if done:
            break
    return alpha, beta, r


@njit(cache=True, nogil=True, error_model="numpy")
def _weighted_moments(z: np.ndarray, w: np.ndarray, mean: np.ndarray, cov: np.ndarray, diff: np.ndarray) -> None:
    """Mean and biased covariance of the points ``z`` (n, p) with 0/1 weights ``w`` (two-pass), and
    every point's offset ``diff`` from that mean."""
    n, p = z.shape
    count = 0.0
    mean[:] = 0.0
    for i in range(n):
        if w[i]:
            count += 1.0
            for j in range(p):
                mean[j] += z[i, j]
    for j in range(p):
        mean[j] /= count
    cov[:] = 0.0
    for i in range(n):
        for j in range(p):
            diff[i, j] = z[i, j] - mean[j]
        if w[i]:
            for j in range(p):
                for k in range(p):
                    cov[j, k] += diff[i, j] * diff[i, k]
    for j in range(p):
        for k in range(p):
            cov[j, k] /= count


@njit(cache=True, nogil=True, error_model="numpy")
def _mahalanobis(diff: np.ndarray, cov: np.ndarray, out: np.ndarray) -> bool:
    """Squared Mahalanobis lengths of the rows of ``diff`` under ``cov`` (p <= 3, closed-form inverse)
    into ``out``; False (``out`` untouched) when ``cov`` is singular (its determinant <= 0)."""
    p = cov.shape[0]
    inv = np.empty((p, p))
    if p == 1:
        det = cov[0, 0]
        inv[0, 0] = 1.0
    elif p == 2:
        a, b, d = cov[0, 0], cov[0, 1], cov[1, 1]
        det = a * d - b * b
        inv[0, 0], inv[1, 1], inv[0, 1], inv[1, 0] = d, a, -b, -b
    else:
        a, b, c = cov[0, 0], cov[0, 1], cov[0, 2]
        e, f, i = cov[1, 1], cov[1, 2], cov[2, 2]
        inv[0, 0], inv[1, 1], inv[2, 2] = e * i - f * f, a * i - c * c, a * e - b * b
        inv[0, 1] = inv[1, 0] = c * f - b * i
        inv[0, 2] = inv[2, 0] = b * f - c * e
        inv[1, 2] = inv[2, 1] = b * c - a * f
        det = a * inv[0, 0] + b * inv[0, 1] + c * inv[0, 2]
    if not det > 0:
        return False
    for j in range(p):
        for k in range(p):
            inv[j, k] /= det
    for r in range(diff.shape[0]):
        acc = 0.0
        for j in range(p):
            v = 0.0
            for k in range(p):
                v += diff[r, k] * inv[k, j]
            acc += v * diff[r, j]
        out[r] = acc
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def mcd_finish(z: np.ndarray, subset: np.ndarray, med_q: float, q: float, reweight: float):
    """FAST-MCD's consistency correction and reweighting (``measure.mcd._finish``) in normalised
    coordinates ``z`` (n, p) of the best h-subset ``subset``: the raw mean and covariance, the latter
    times median(d²) / ``med_q``; the support d² <= ``q`` and its mean and covariance times
    ``reweight``; every point's d² under them. The first value is False when a covariance is singular
    (the caller's numpy path takes its pseudo-inverse)."""
    n, p = z.shape
    raw_mean, raw_cov = np.empty(p), np.empty((p, p))
    mean, cov = np.empty(p), np.empty((p, p))
    diff, d2, work = np.empty((n, p)), np.empty(n), np.empty(n)
    support = np.empty(n, np.bool_)
    _weighted_moments(z, subset, raw_mean, raw_cov, diff)
    if not _mahalanobis(diff, raw_cov, d2):
        return False, raw_mean, raw_cov, support, mean, cov, d2
    work[:] = d2
    a, b = _ends(work, (n - 1) // 2, n // 2)
    factor = (a + b) / 2.0 / med_q
    if factor > 0:
        for j in range(p):
            for k in range(p):
                raw_cov[j, k] *= factor
        for i in range(n):
            d2[i] /= factor
    for i in range(n):
        support[i] = d2[i] <= q
    _weighted_moments(z, support, mean, cov, diff)
    for j in range(p):
        for k in range(p):
            cov[j, k] *= reweight
    if not _mahalanobis(diff, cov, d2):
        return False, raw_mean, raw_cov, support, mean, cov, d2
    return True, raw_mean, raw_cov, support, mean, cov, d2


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _distances(coef: np.ndarray, mono: np.ndarray, out: np.ndarray) -> None:
    """d² = max(coef · mono_i, 0) of every point i, the terms summed in order with fused multiply-adds:
    as OpenBLAS's gemm kernel adds them, the same bits as ``coef @ mono.T`` (the one function compiled
    with contraction)."""
    m = coef.size
    for i in range(mono.shape[0]):
        acc = coef[0] * mono[i, 0]
        for k in range(1, m):
            acc += coef[k] * mono[i, k]
        out[i] = acc if acc > 0.0 else 0.0



@njit(cache=True, nogil=True, error_model="numpy")
def few_starts_masks(mono: np.ndarray, mean: np.ndarray, cov: np.ndarray, lam: np.ndarray, h: int) -> np.ndarray:
    """The subset masks (G, S, n) of one C-step (``measure.cstep.c_step``) in double precision for G x S
    starts on G point sets (``mono`` G x n x m), in one call: each start's coefficients
    (``start_coefficients``), every point's d² (the bits of the BLAS product) and the points at or below
    the h-th smallest (a selection: the set the partition of the bit patterns gives)."""
    g_n, s_n, _ = mean.shape
    n = mono.shape[1]
    coef = start_coefficients(mean, cov, lam)
    masks = np.empty((g_n, s_n, n), np.bool_)
    d2, work = np.empty(n), np.empty(n)
    for g in range(g_n):
        for s in range(s_n):
            _distances(coef[g, s], mono[g], d2)
            work[:] = d2
            kth = _select(work, 0, n - 1, h - 1)
            for i in range(n):
                masks[g, s, i] = d2[i] <= kth
    return masks
