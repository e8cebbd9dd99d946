"""The robust line's and FAST-MCD's compiled loops (numba) beside ``measure.kernels``: the Tukey IRLS of
the disparity line (``bisquare_line``) and the line's steps after its FAST-MCD start (``robust_line``:
the scales, the second start and the support), FAST-MCD's consistency correction and reweighting
(``mcd_finish``), a C-step's distances for a few starts (``_distances``) and Tukey's bisquare location
of a run of values (``bisquare_location``, ``measure.robust_range.tukey_location``: its sums in numpy's
pairwise order, so the same bits as the numpy loop).

Each does numpy's element-wise operations; sums over the samples are added in sample order, where a
BLAS product adds them in another, so their last bits can differ from the numpy formulation they
replaced (docs/decisions/core-speed.md: no verdict, fit or gap changed). Medians and the least trimmed
squares' h smallest come from a selection (the same order statistics). Compiled on first use and
cached on disk (numba ``cache=True``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from measure.kernels import _ends, _select
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
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of ``a[lo:lo + n]`` for n <= 128: one by one below 8, else eight running sums."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - n % 8:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, nogil=True, error_model="numpy")
def _pairwise_sum(a: np.ndarray, n: int) -> float:
    """sum of ``a[:n]`` added as numpy adds a contiguous float64 array (its pairwise summation: blocks of
    up to 128 values by ``_block_sum``, longer runs split in halves, rounded down to a multiple of 8, summed
    apart and added; the reduction starts from the identity 0), so the same bits as ``a[:n].sum()``. The
    halves are walked with a stack of tasks, not by recursion (numba's disk cache cannot hold a recursive
    function)."""
    if n <= 128:
        return _block_sum(a, 0, n)
    task_lo, task_n = np.empty(128, np.int64), np.empty(128, np.int64)  # task_n -1: add the last two values
    values = np.empty(128)
    tasks, top = 1, 0
    task_lo[0], task_n[0] = 0, n
    while tasks:
        tasks -= 1
        lo, k = task_lo[tasks], task_n[tasks]
        if k < 0:
            top -= 1
            values[top - 1] += values[top]
        elif k <= 128:
            values[top] = _block_sum(a, lo, k)
            top += 1
        else:
            half = k // 2
            half -= half % 8
            task_lo[tasks], task_n[tasks] = 0, -1
            task_lo[tasks + 1], task_n[tasks + 1] = lo + half, k - half
            task_lo[tasks + 2], task_n[tasks + 2] = lo, half
            tasks += 3
    return values[0]


@njit(cache=True, nogil=True, error_model="numpy")
def bisquare_location(v: np.ndarray, m: float, c: float, s: float, iterations: int) -> tuple[float, float]:
    """Tukey's bisquare location of ``v`` from the start ``m`` at the fixed scale ``c`` ``s`` and its standard
    error (``measure.robust_range.tukey_location``, s > 0): per iteration the weights max(1 - u², 0)² of
    u = (v - m) / (c s) and their weighted mean, until it moves by at most 1e-12 of max(1, |m|); then the
    RMS deviation of the samples with |u| < 1 over the root of their count. numpy's element-wise
    operations and its pairwise sums (``_pairwise_sum``): the same bits as the numpy loop it replaced."""
    n = v.size
    cs = c * s
    w, wv = np.empty(n), np.empty(n)
    for _ in range(iterations):
        for i in range(n):
            x = (v[i] - m) / cs
            x = max(1.0 - x * x, 0.0)
            x *= x
            w[i] = x
            wv[i] = x * v[i]
        m_new = _pairwise_sum(wv, n) / _pairwise_sum(w, n)
        done = abs(m_new - m) <= 1e-12 * max(1.0, abs(m))
        m = m_new
        if done:
            break
    count = 0
    for i in range(n):
        x = v[i] - m
        if abs(x / cs) < 1.0:
            w[count] = x * x
            count += 1
    spread = np.sqrt(_pairwise_sum(w, count) / count) if count else 0.0
    return m, (spread if spread > 0 else s) / np.sqrt(max(1, count))


@njit(cache=True, nogil=True, error_model="numpy")
def _middle(a: np.ndarray, k: int) -> float:
    """The median of the ``k`` smallest values of ``a`` (reordered): the mean of its order statistics
    (k - 1) // 2 and k // 2, as ``np.median`` of those k values gives them."""
    lo, hi = _ends(a, (k - 1) // 2, k // 2)
    return (lo + hi) / 2.0


@njit(cache=True, nogil=True, error_model="numpy")
def _lts(r: np.ndarray, h: int, work: np.ndarray) -> float:
    """Least trimmed squares: the sum of the ``h`` smallest r²."""
    for i in range(r.size):
        work[i] = r[i] * r[i]
    _select(work, 0, r.size - 1, h - 1)  # the h smallest end up first
    total = 0.0
    for i in range(h):
        total += work[i]
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def robust_line(t: np.ndarray, d: np.ndarray, start_support: np.ndarray, alpha: float, beta: float, floor: float, has_alt: bool,
                alt_alpha: float, alt_beta: float, h: int, iterations: int):  # fmt: skip
    """Steps 2 and 3 of ``measure.dline.fit_disparity_line`` after FAST-MCD's start (``alpha``, ``beta``;
    ``start_support``: its support): the IRLS (``bisquare_line``) at the scale max(1.4826 MAD of the start's
    support residuals, ``floor``, 1e-6); with ``has_alt``, the second start's two IRLS runs (at the scale of
    its ``h`` best residuals, then at the tighter scale) unless it lies within the tight band of the line at
    both ends, and the winner by least trimmed squares and support. Returns alpha, beta, the scale (px),
    the support |r| < ``TUKEY_C`` scale, the RMS residual on it (at least ``floor``; the scale when empty),
    its count and the sum of its t and t² (the normal equations' terms)."""
    n = t.size
    work = np.empty(n)
    k = 0
    for i in range(n):
        if start_support[i]:
            work[k] = abs(d[i] - (alpha + beta * t[i]))
            k += 1
    scale = max(max(1.4826 * _middle(work[:k], k), floor), 1e-6)
    alpha, beta, r = bisquare_line(t, d, alpha, beta, scale, iterations)
    if has_alt:
        for i in range(n):
            work[i] = abs(d[i] - (alt_alpha + alt_beta * t[i]))
        scale_a = max(max(1.4826 * _middle(work, h), floor), 1e-6)
        tight = min(scale, scale_a)
        lo, hi = t.min(), t.max()
        apart = max(abs(alt_alpha + alt_beta * lo - (alpha + beta * lo)), abs(alt_alpha + alt_beta * hi - (alpha + beta * hi)))
        if apart > TUKEY_C * tight:
            a2, b2, r2 = bisquare_line(t, d, alt_alpha, alt_beta, scale_a, iterations)
            a2, b2, r2 = bisquare_line(t, d, a2, b2, tight, iterations)
            band = TUKEY_C * tight
            in1, in2 = 0, 0
            for i in range(n):
                in1 += int(abs(r[i]) < band)
                in2 += int(abs(r2[i]) < band)
            if _lts(r2, h, work) < _lts(r, h, work) and in2 > in1:
                alpha, beta, r, scale = a2, b2, r2, tight
    support = np.empty(n, np.bool_)
    limit = TUKEY_C * scale
    ns, ss, st, stt = 0, 0.0, 0.0, 0.0
    for i in range(n):
        support[i] = abs(r[i]) < limit
        if support[i]:
            ns += 1
            ss += r[i] * r[i]
            st += t[i]
            stt += t[i] * t[i]
    sigma = max(np.sqrt(ss / ns) if ns else scale, floor)
    return alpha, beta, scale, support, sigma, ns, st, stt
