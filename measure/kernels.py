"""The measurement core's compiled loops (numba): the per-start arithmetic of FAST-MCD's C-step
(``start_coefficients``, ``moments_det_lam``), the crease search's candidates, fits, medians and MADs
(``crease_candidates``, ``trimmed_crease_fits``, ``row_scales``), and a 1-D median (``median_1d``) and
lag-one autocorrelation (``lag_one_correlation``) for ``measure.robust_range`` and ``measure.uncertainty``.

The C-step kernels do, element by element, the float64 operations of the numpy formulation they replaced,
in the same order (numpy's einsum adds three terms as first + last, then the middle one), so their
numbers are the same bit for bit. Medians and MADs come from a selection (quickselect, long rows first
narrowed to a bracket) instead of a sort: order statistics are values of the input, the same whatever
the algorithm. The crease fits sum their normal equations in the loop (the trimmed second fit's sums
vectorised) and solve them by Gaussian elimination instead of BLAS and LAPACK, whose rounding a loop
does not reproduce: within 1e-9 px of it. tests/measure/test_kernels.py and test_mcd_kernels.py hold
each kernel to its numpy oracle. Compiled on first use and cached on disk (numba ``cache=True``);
measured reasons and the first-call cost: docs/decisions/core-speed.md.
"""

from __future__ import annotations

import numpy as np
from numba import njit

RIDGE = 1e-8  # regularises singular starts (relative to the start's scale, at least 1)
_SMALL = 16  # below this many values a selection sorts by insertion
_LONG, _SAMPLE, _MARGIN = 128, 64, 8  # rows from _LONG values on are narrowed by a sample first (_pair)


@njit(cache=True, nogil=True, error_model="numpy")
def _select(a: np.ndarray, lo: int, hi: int, k: int) -> float:
    """The k-th smallest of ``a[lo:hi + 1]`` (reordered in place: smaller values end up before k, larger
    after it); quickselect with a median-of-three pivot, insertion sort for short ranges."""
    while hi - lo >= _SMALL:
        mid = (lo + hi) >> 1
        x, y, z = a[lo], a[mid], a[hi]
        if x > y:
            x, y = y, x
        if y > z:
            y = z
        if x > y:
            y = x
        i, j = lo, hi
        while i <= j:
            while a[i] < y:
                i += 1
            while a[j] > y:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return a[k]
    for i in range(lo + 1, hi + 1):
        v = a[i]
        j = i - 1
        while j >= lo and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v
    return a[k]


@njit(cache=True, nogil=True, error_model="numpy")
def _pair(a: np.ndarray, lo: int, hi: int, window: np.ndarray, low: float = -np.inf, high: float = np.inf) -> tuple[float, float]:
    """The ``lo``-th and ``hi``-th smallest (``hi`` = ``lo`` or ``lo`` + 1) of ``a`` (reordered).

    Long rows first narrow the search (Floyd and Rivest's idea): one pass counts the values below a
    bracket and copies those within it into ``window``, and when ``lo`` and ``hi`` fall among them the
    selection runs on those alone. The bracket is ``low``, ``high`` when given (a neighbouring row's
    answer), then ``_SAMPLE`` values at even strides, whose order statistics ``_MARGIN`` ranks either
    side of rank ``lo``'s expected place bound it. Otherwise (or on short rows) the selection runs on the
    whole row."""
    n = a.size
    if n < _LONG:
        return _ends(a, lo, hi)
    if low > -np.inf or high < np.inf:
        ok, first, second = _bracketed(a, lo, hi, window, low, high)
        if ok:
            return first, second
    sample = window[n - _SAMPLE :]  # the window's tail, read before the pass below fills the window
    for i in range(_SAMPLE):
        sample[i] = a[((2 * i + 1) * n) // (2 * _SAMPLE)]
    at = (lo * _SAMPLE) // n
    low, high = -np.inf, np.inf
    if at >= _MARGIN:
        low = _select(sample, 0, _SAMPLE - 1, at - _MARGIN)
    if at + _MARGIN < _SAMPLE:
        high = _select(sample, max(at - _MARGIN + 1, 0), _SAMPLE - 1, at + _MARGIN)
    ok, first, second = _bracketed(a, lo, hi, window, low, high)
    if ok:
        return first, second
    return _ends(a, lo, hi)


@njit(cache=True, nogil=True, error_model="numpy")
def _bracketed(a: np.ndarray, lo: int, hi: int, window: np.ndarray, low: float, high: float) -> tuple[bool, float, float]:
    """(True, the lo-th and hi-th smallest of ``a``) when both lie in [``low``, ``high``], else False."""
    below, count = 0, 0
    # Without branches: whether a value is below or within the bracket is a coin toss the processor
    # cannot predict (a miss costs more than the store); every value is written, the count advances
    # past those within.
    for i in range(a.size):
        v = a[i]
        below += int(v < low)
        window[count] = v
        count += int(v >= low) & int(v <= high)
    if below <= lo and hi < below + count:
        first, second = _ends(window[:count], lo - below, hi - below)
        return True, first, second
    return False, 0.0, 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _ends(a: np.ndarray, lo: int, hi: int) -> tuple[float, float]:
    n = a.size
    first = _select(a, 0, n - 1, lo)
    if hi == lo:
        return first, first
    second = a[hi]
    for i in range(hi + 1, n):
        if a[i] < second:
            second = a[i]
    return first, second


@njit(cache=True, nogil=True, error_model="numpy")
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """sum a_j b_j for 1-3 terms, added in the order of numpy's einsum (for three: the first and the
    last, then the middle one)."""
    if a.size == 1:
        return a[0] * b[0]
    if a.size == 2:
        return a[0] * b[0] + a[1] * b[1]
    return (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]


@njit(cache=True, nogil=True, error_model="numpy")
def start_coefficients(mean: np.ndarray, cov: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Per start (``mean`` (G, S, p), ``cov`` (G, S, p, p), ``lam`` its lambda_min estimate (G, S)): the
    coefficients (G, S, m) of its squared Mahalanobis distance in the monomials (1, z_j, z_j z_k for
    j <= k). Steps: a ridge of ``RIDGE`` times the trace (at least 1) on every start's diagonal when any
    start is singular (lambda_min at or below its ridge), the closed-form determinant and adjugate, the
    inverse, then the constant, linear and quadratic terms."""
    g_n, s_n, p = mean.shape
    m = 1 + p + p * (p + 1) // 2
    # The ridge and the singularity test scale with the trace: a start spanning far outliers has a
    # covariance of up to 1e24 whose rounding alone exceeds an absolute ridge (its determinant
    # could come out zero or negative). At data scale (trace <= 1) it is the absolute 1e-8.
    ridge = np.empty((g_n, s_n))
    singular = False
    for g in range(g_n):
        for s in range(s_n):
            tr = cov[g, s, 0, 0]
            for j in range(1, p):
                tr += cov[g, s, j, j]
            ridge[g, s] = RIDGE * max(tr, 1.0)
            singular |= lam[g, s] <= ridge[g, s]
    coef = np.empty((g_n, s_n, m))
    c = np.empty((p, p))
    inv = np.empty((p, p))
    for g in range(g_n):
        for s in range(s_n):
            add = ridge[g, s] if lam[g, s] <= ridge[g, s] else 0.0
            for j in range(p):
                for k in range(p):
                    c[j, k] = cov[g, s, j, k] + (add * (1.0 if j == k else 0.0)) if singular else cov[g, s, j, k]
            if p == 1:
                det = c[0, 0]
                inv[0, 0] = 1.0 / det
            elif p == 2:
                a, b, d = c[0, 0], c[0, 1], c[1, 1]
                det = a * d - b * b
                inv[0, 0], inv[1, 1] = d / det, a / det
                inv[0, 1] = inv[1, 0] = -b / det
            else:
                a, b, cc = c[0, 0], c[0, 1], c[0, 2]
                e, f, i = c[1, 1], c[1, 2], c[2, 2]
                a00, a01, a02 = e * i - f * f, cc * f - b * i, b * f - cc * e
                a11, a12, a22 = a * i - cc * cc, b * cc - a * f, a * e - b * b
                det = a * a00 + b * a01 + cc * a02
                inv[0, 0], inv[1, 1], inv[2, 2] = a00 / det, a11 / det, a22 / det
                inv[0, 1] = inv[1, 0] = a01 / det
                inv[0, 2] = inv[2, 0] = a02 / det
                inv[1, 2] = inv[2, 1] = a12 / det
            for j in range(p):
                coef[g, s, 1 + j] = -2.0 * _dot(inv[j], mean[g, s])
            coef[g, s, 0] = -0.5 * _dot(coef[g, s, 1 : 1 + p], mean[g, s])
            q = 1 + p
            for j in range(p):
                for k in range(j, p):
                    coef[g, s, q] = (1.0 if j == k else 2.0) * inv[j, k]
                    q += 1
    return coef


@njit(cache=True, nogil=True, error_model="numpy")
def moments_det_lam(sums: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean (G, S, p), biased covariance (G, S, p, p), determinant and lambda_min estimate det / trace(adj)
    (each G, S) from summed monomials (G, S, m; the count first). det / trace(adj) lies within a factor p
    of the smallest eigenvalue: a cheap singularity test (0 where the covariance is zero)."""
    g_n, s_n, _ = sums.shape
    mean = np.empty((g_n, s_n, p))
    cov = np.empty((g_n, s_n, p, p))
    det = np.empty((g_n, s_n))
    lam = np.empty((g_n, s_n))
    for g in range(g_n):
        for s in range(s_n):
            w = sums[g, s, 0]
            for j in range(p):
                mean[g, s, j] = sums[g, s, 1 + j] / w
            q = 1 + p
            for j in range(p):
                for k in range(j, p):
                    cov[g, s, j, k] = cov[g, s, k, j] = sums[g, s, q] / w - mean[g, s, j] * mean[g, s, k]
                    q += 1
            c = cov[g, s]
            if p == 1:
                dt, tr = c[0, 0], np.inf
                lam[g, s] = dt
            elif p == 2:
                a, b, d = c[0, 0], c[0, 1], c[1, 1]
                dt, tr = a * d - b * b, d + a
            else:
                a, b, cc = c[0, 0], c[0, 1], c[0, 2]
                e, f, i = c[1, 1], c[1, 2], c[2, 2]
                m00 = e * i - f * f
                dt = a * m00 + b * (cc * f - b * i) + cc * (b * f - cc * e)
                tr = m00 + (a * i - cc * cc) + (a * e - b * b)
            det[g, s] = dt
            if p > 1:
                lam[g, s] = dt / (tr if tr > 0 else np.inf)
    return mean, cov, det, lam


@njit(cache=True, nogil=True, error_model="numpy")
def _scale_of(r: np.ndarray, floor: float, work: np.ndarray, window: np.ndarray, near: float = np.nan,
              mad_near: float = np.nan) -> tuple[float, float, float]:  # fmt: skip
    """The robust scale max(1.4826 MAD, ``floor``) of ``r``, its median and its MAD; ``work`` holds a copy
    of ``r`` (reordered here), ``window`` is a buffer of its size. ``near``, ``mad_near``: a neighbouring
    row's median and MAD (NaN: none), to bracket the selections."""
    n = r.size
    lo, hi = (n - 1) // 2, n // 2
    if near == near and mad_near > 0:
        a, b = _pair(work, lo, hi, window, near - 0.25 * mad_near, near + 0.25 * mad_near)
    else:
        a, b = _pair(work, lo, hi, window)
    m = 0.5 * (a + b)
    for i in range(n):
        work[i] = abs(r[i] - m)
    if mad_near > 0:
        a, b = _pair(work, lo, hi, window, 0.9 * mad_near, 1.1 * mad_near)
    else:
        a, b = _pair(work, lo, hi, window)
    mad = 0.5 * (a + b)
    return max(1.4826 * mad, floor), m, mad


@njit(cache=True, nogil=True, error_model="numpy")
def _residuals(t: np.ndarray, d: np.ndarray, t0: float, b0: float, b1: float, b2: float, r: np.ndarray, work: np.ndarray) -> None:
    """r = d - b0 - b1 t - b2 max(t - t0, 0), into ``r`` and ``work``."""
    for i in range(t.size):
        x = d[i] - b0
        x -= b1 * t[i]
        x -= b2 * max(t[i] - t0, 0.0)
        r[i] = x
        work[i] = x


@njit(cache=True, nogil=True, error_model="numpy")
def row_scales(t: np.ndarray, d: np.ndarray, t0: np.ndarray, beta: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Per candidate k of the crease search: the residuals r = d - b0 - b1 t - b2 max(t - t0_k, 0) of its
    coefficients ``beta[k]`` (an infinite ``t0`` is the one line), their robust scale max(1.4826 MAD,
    ``floor``) and their median."""
    k_n, n = beta.shape[0], t.size
    scale = np.empty(k_n)
    med = np.empty(k_n)
    r, work, window = np.empty(n), np.empty(n), np.empty(n)
    mad = np.nan
    for k in range(k_n):
        _residuals(t, d, t0[k], beta[k, 0], beta[k, 1], beta[k, 2], r, work)
        scale[k], med[k], mad = _scale_of(r, floor, work, window, med[k - 1] if k > 0 else np.nan, mad if k > 0 else np.nan)
    return scale, med


@njit(cache=True, nogil=True, error_model="numpy")
def _solve3(a: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """x of a x = y for a 3x3 ``a`` (overwritten, as ``y``): Gaussian elimination with partial pivoting."""
    for c in range(3):
        p = c
        for r in range(c + 1, 3):
            if abs(a[r, c]) > abs(a[p, c]):
                p = r
        if p != c:
            for j in range(3):
                a[c, j], a[p, j] = a[p, j], a[c, j]
            y[c], y[p] = y[p], y[c]
        for r in range(c + 1, 3):
            f = a[r, c] / a[c, c]
            for j in range(c + 1, 3):
                a[r, j] -= f * a[c, j]
            y[r] -= f * y[c]
    x2 = y[2] / a[2, 2]
    x1 = (y[1] - a[1, 2] * x2) / a[1, 1]
    x0 = (y[0] - a[0, 1] * x1 - a[0, 2] * x2) / a[0, 0]
    return x0, x1, x2


@njit(cache=True, nogil=True, error_model="numpy")
def _hinge_fit(t: np.ndarray, d: np.ndarray, t0: float, r: np.ndarray, m: float, limit: float, a: np.ndarray,
               y: np.ndarray) -> tuple[float, float, float]:  # fmt: skip
    """Least squares of d on 1, t and max(t - t0, 0) over the samples with |r - m| <= ``limit``, from the
    normal equations (a ridge of 1e-9 on the diagonal, as an infinite ``t0``'s zero column needs)."""
    s = _trimmed_sums(t, d, t0, r, m, limit)
    a[0, 0], a[0, 1], a[1, 1], a[0, 2], a[1, 2], a[2, 2] = s[0], s[1], s[2], s[3], s[4], s[5]
    y[0], y[1], y[2] = s[6], s[7], s[8]
    a[1, 0], a[2, 0], a[2, 1] = a[0, 1], a[0, 2], a[1, 2]
    for j in range(3):
        a[j, j] += 1e-9
    return _solve3(a, y)


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _trimmed_sums(t: np.ndarray, d: np.ndarray, t0: float, r: np.ndarray, m: float, limit: float):
    """The normal equations' sums of :func:`_hinge_fit` (1, t, t², h, t h, h², d, t d, h d with
    h = max(t - t0, 0)) over the samples with |r - m| <= ``limit``: 0/1 weights without branches, added in
    the order the compiler vectorises."""
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = 0.0
    for i in range(t.size):
        w = 1.0 if abs(r[i] - m) <= limit else 0.0
        ti, di = t[i], d[i]
        h = max(ti - t0, 0.0)
        wt, wh = w * ti, w * h
        s0 += w
        s1 += wt
        s2 += wt * ti
        s3 += wh
        s4 += wt * h
        s5 += wh * h
        s6 += w * di
        s7 += wt * di
        s8 += wh * di
    return s0, s1, s2, s3, s4, s5, s6, s7, s8


@njit(cache=True, nogil=True, error_model="numpy")
def _line_fit_from_tail(tail: np.ndarray, j: int, t0: float, a: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """The least-squares fit of :func:`_hinge_fit` on all samples, from the sums of 1, t, t², d and t d
    over the samples sorted by t from position ``j`` on (``tail``, row j; row 0: all of them), the first
    past ``t0``: max(t - t0, 0) is t - t0 there and 0 before, so its sums are those sums' combinations."""
    n1, st, stt, sd, std = tail[0]
    m1, mt, mtt, md, mtd = tail[j]
    a[0, 0], a[0, 1], a[1, 1] = n1, st, stt
    y[0], y[1] = sd, std
    if m1 > 0:
        a[0, 2] = mt - t0 * m1
        a[1, 2] = mtt - t0 * mt
        a[2, 2] = mtt - 2.0 * t0 * mt + t0 * t0 * m1
        y[2] = mtd - t0 * md
    else:  # no sample past the crease (the one line's infinite t0): a zero column
        a[0, 2] = a[1, 2] = a[2, 2] = y[2] = 0.0
    a[1, 0], a[2, 0], a[2, 1] = a[0, 1], a[0, 2], a[1, 2]
    for i in range(3):
        a[i, i] += 1e-9
    return _solve3(a, y)


@njit(cache=True, nogil=True, error_model="numpy")
def trimmed_crease_fits(t: np.ndarray, d: np.ndarray, t0: np.ndarray, floor: float) -> np.ndarray:
    """Per crease ``t0[k]`` (infinite: the one line): the least-squares continuous two-piece line
    d = b0 + b1 t + b2 max(t - t0, 0) on all samples, then again on the samples within 3 robust scales
    (max(1.4826 MAD, ``floor``)) of its residuals' median; returns the second fits' (b0, b1, b2), (K, 3).
    The first fits come from running sums over the samples sorted by t (one pass for all creases)."""
    n = t.size
    order = np.argsort(t)
    ts = t[order]
    tail = np.zeros((n + 1, 5))
    for i in range(n - 1, -1, -1):
        ti, di = ts[i], d[order[i]]
        tail[i, 0] = tail[i + 1, 0] + 1.0
        tail[i, 1] = tail[i + 1, 1] + ti
        tail[i, 2] = tail[i + 1, 2] + ti * ti
        tail[i, 3] = tail[i + 1, 3] + di
        tail[i, 4] = tail[i + 1, 4] + ti * di
    beta = np.empty((t0.size, 3))
    a, y = np.empty((3, 3)), np.empty(3)
    r, work, window = np.zeros(n), np.empty(n), np.empty(n)
    m, mad = np.nan, np.nan
    for k in range(t0.size):
        b0, b1, b2 = _line_fit_from_tail(tail, np.searchsorted(ts, t0[k], side="right"), t0[k], a, y)
        _residuals(t, d, t0[k], b0, b1, b2, r, work)
        # neighbouring creases have nearly the same residuals: the last row's median and MAD bracket this one's
        s, m, mad = _scale_of(r, floor, work, window, m, mad)
        beta[k, 0], beta[k, 1], beta[k, 2] = _hinge_fit(t, d, t0[k], r, m, 3.0 * s, a, y)
    return beta


@njit(cache=True, nogil=True, error_model="numpy")
def crease_candidates(t: np.ndarray, d: np.ndarray, length: float, quantum: float, floor: float, min_px: float, min_samples: int,
                      candidates: int, disagree: float):  # fmt: skip
    """The crease search's first part (``measure.bend.hinge_ends``): ``candidates`` creases evenly from
    ``min_px`` to ``length`` - ``min_px`` (as ``np.linspace``), those with ``min_samples`` samples on each
    side; the one line's and every crease's trimmed fits (``trimmed_crease_fits``); the one line's robust
    scale and median. Returns the creases (K,), their fits (K, 3), the one line's (3,), scale and median,
    and whether any crease's pieces part by more than ``quantum`` and ``disagree`` of the disparity at the
    crease (condition 3 without its scale term)."""
    n = t.size
    ts = np.sort(t)
    step = ((length - min_px) - min_px) / (candidates - 1)
    creases = np.empty(candidates + 1)
    creases[0] = np.inf
    k = 1
    for i in range(candidates):
        t0 = i * step + min_px if i < candidates - 1 else length - min_px
        left = np.searchsorted(ts, t0)
        if left >= min_samples and n - left >= min_samples:
            creases[k] = t0
            k += 1
    beta = trimmed_crease_fits(t, d, creases[:k], floor)
    scale, med = row_scales(t, d, creases[:1], beta[:1], floor)
    parted = False
    for j in range(1, k):
        t0 = creases[j]
        part = abs(beta[j, 2]) * min(t0, length - t0)
        parted |= part > max(quantum, disagree * abs(beta[j, 0] + beta[j, 1] * t0))
    return creases[1:k], beta[1:], beta[0], scale[0], med[0], parted


@njit(cache=True, nogil=True, error_model="numpy")
def _median(v: np.ndarray, work: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D ``v`` by selection in ``work`` (at least ``v.size`` long): its
    middle value, or the mean of the two middle ones (the same order statistics, the same bits)."""
    n = v.size
    work[:n] = v
    a, b = _ends(work[:n], (n - 1) // 2, n // 2)
    return (a + b) / 2.0 if n % 2 == 0 else a


@njit(cache=True, nogil=True, error_model="numpy")
def median_1d(v: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D ``v`` (:func:`_median`)."""
    return _median(v, np.empty(v.size))


@njit(cache=True, nogil=True, error_model="numpy")
def lag_one_correlation(r: np.ndarray) -> float:
    """The lag-one autocorrelation sum (r_i - m)(r_i+1 - m) / sum (r_i - m)² of ``r`` (m its mean;
    0 when every value is the mean), summed in order."""
    n = r.size
    m = 0.0
    for i in range(n):
        m += r[i]
    m /= n
    den, num = 0.0, 0.0
    for i in range(n):
        x = r[i] - m
        den += x * x
        if i + 1 < n:
            num += x * (r[i + 1] - m)
    return num / den if den > 0 else 0.0
