"""FAST-MCD's compiled loops (numba) around its C-steps (``measure.mcd``, ``measure.cstep``): the robust
normalisation and the monomials (``normalised``, step 1 of ``measure.mcd``), the random starts' moments
(``start_moments``), a C-step's masks and summed monomials after numpy's selection (``masked_sums``) and
a whole C-step for a few starts (``few_starts_step``), the subsample stages' best candidates (``keep_best``)
and the full-data stage with its bookkeeping (``full_data_stage``).

Each replaced a dozen numpy calls whose overhead exceeded their arithmetic on a few hundred points. The
order statistics (medians, MADs, the h-th smallest d²) are the values numpy selects; the sums over the
points are added in an order the compiler may vectorise (``fastmath`` reassociation) where numpy's
reductions and BLAS add them in theirs, so the last bits can differ from the numpy formulation (moments
within about 1e-15 relative; the answers: docs/decisions/core-speed.md, sixth round). tests/measure/
test_mcd_kernels.py and test_mcd.py hold each to its numpy oracle. Compiled on first use and cached on disk.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from measure.fit_kernels import _distances
from measure.kernels import _median, _pair, moments_det_lam, start_coefficients


@njit(cache=True, nogil=True, error_model="numpy")
def normalised(x: np.ndarray, max_spread: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Step 1 of ``measure.mcd`` for points ``x`` (n, p): the coordinate-wise median ``center``, the scale
    s = sqrt(sum of (1.4826 MAD)²) (the root of the summed variances when every MAD is zero), at least the
    farthest coordinate's |x - center| / ``max_spread``; z = (x - center) / s (zeros when s = 0) and z's
    monomials (1, z_1..z_p, z_j z_k for j <= k) as (n, m) and (m, n) arrays."""
    n, p = x.shape
    m = 1 + p + p * (p + 1) // 2
    center = np.empty(p)
    col, work = np.empty(n), np.empty(n)
    s2, dev_max = 0.0, 0.0
    for j in range(p):
        for i in range(n):
            col[i] = x[i, j]
        center[j] = _median(col, work)
        for i in range(n):
            col[i] = abs(x[i, j] - center[j])
            dev_max = max(dev_max, col[i])
        mad = 1.4826 * _median(col, work)
        s2 += mad * mad
    s = np.sqrt(s2)
    if s == 0.0:
        for j in range(p):
            mean = 0.0
            for i in range(n):
                mean += x[i, j]
            mean /= n
            var = 0.0
            for i in range(n):
                var += (x[i, j] - mean) ** 2
            s2 += var / n
        s = np.sqrt(s2)
    s = max(s, dev_max / max_spread)
    z = np.zeros((n, p))
    mono = np.empty((n, m))
    mono_t = np.empty((m, n))
    for i in range(n):
        if s > 0:
            for j in range(p):
                z[i, j] = (x[i, j] - center[j]) / s
        mono[i, 0] = 1.0
        q = 1 + p
        for j in range(p):
            mono[i, 1 + j] = z[i, j]
            for k in range(j, p):
                mono[i, q] = z[i, j] * z[i, k]
                q += 1
        for k in range(m):
            mono_t[k, i] = mono[i, k]
    return center, s, z, mono, mono_t


@njit(cache=True, nogil=True, error_model="numpy")
def start_moments(mono: np.ndarray, draw: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The random starts' mean, covariance, determinant and lambda_min estimate (``moments_det_lam``; each
    (G, S, ...)) from the monomials (n, m) of the points ``draw`` (G, S (p + 1): each start's p + 1
    point indices in turn)."""
    g_n, k = draw.shape
    s_n, m = k // (p + 1), mono.shape[1]
    sums = np.zeros((g_n, s_n, m))
    for g in range(g_n):
        for s in range(s_n):
            for u in range(p + 1):
                i = draw[g, s * (p + 1) + u]
                for j in range(m):
                    sums[g, s, j] += mono[i, j]
    return moments_det_lam(sums, p)


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _row_sums(w: np.ndarray, mono_t: np.ndarray, out: np.ndarray) -> None:
    """out_j = sum_i w_i mono_t[j, i] (added in the order the compiler vectorises)."""
    for j in range(mono_t.shape[0]):
        x = mono_t[j]
        acc = 0.0
        for i in range(w.size):
            acc += w[i] * x[i]
        out[j] = acc


@njit(cache=True, nogil=True, error_model="numpy")
def _subset_sums(values: np.ndarray, kth, mono_t: np.ndarray, mask: np.ndarray, w: np.ndarray, sums: np.ndarray) -> None:
    """The subset of the points whose ``values`` (n) are at most ``kth`` into ``mask`` (n bools) and their
    summed monomials (``mono_t`` (m, n)) into ``sums`` (m); ``w`` (n) is scratch for the 0/1 weights."""
    for i in range(values.size):
        b = values[i] <= kth
        mask[i] = b
        w[i] = 1.0 if b else 0.0
    _row_sums(w, mono_t, sums)


@njit(cache=True, nogil=True, error_model="numpy")
def masked_sums(key: np.ndarray, kth: np.ndarray, mono_t: np.ndarray, s0: int, mask: np.ndarray, sums: np.ndarray) -> None:
    """A C-step's subsets after the selection (``measure.cstep.c_step``): for G groups of S starts from
    start ``s0`` on, the points whose d² bit pattern ``key`` (G, S, n) is at most the h-th smallest ``kth``
    (G, S) go into ``mask[g, s0 + s]`` (n bools) and their summed monomials (``mono_t`` (G, m, n)) into
    ``sums[g, s0 + s]`` (m, float64)."""
    g_n, s_n, n = key.shape
    w = np.empty(n)
    for g in range(g_n):
        for s in range(s_n):
            _subset_sums(key[g, s], kth[g, s], mono_t[g], mask[g, s0 + s], w, sums[g, s0 + s])


@njit(cache=True, nogil=True, error_model="numpy")
def few_starts_step(mono: np.ndarray, mono_t: np.ndarray, mean: np.ndarray, cov: np.ndarray, lam: np.ndarray, h: int, p: int):
    """One C-step (``measure.cstep.c_step``) in double precision for G x S starts on G point sets
    (``mono`` G x n x m, ``mono_t`` G x m x n), in one call: each start's coefficients
    (``start_coefficients``), every point's d² (``_distances``), the points at or below the h-th smallest
    (a selection: the set numpy's partition gives), their summed monomials and the new moments. Returns masks (G, S, n), means,
    covariances, determinants and lambda_min estimates."""
    g_n, s_n, _ = mean.shape
    n, m = mono.shape[1], mono.shape[2]
    coef = start_coefficients(mean, cov, lam)
    masks = np.empty((g_n, s_n, n), np.bool_)
    sums = np.empty((g_n, s_n, m))
    d2, work, window, w = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for g in range(g_n):
        for s in range(s_n):
            _distances(coef[g, s], mono[g], d2)
            work[:] = d2
            _subset_sums(d2, _pair(work, h - 1, h - 1, window)[0], mono_t[g], masks[g, s], w, sums[g, s])
    return (masks,) + moments_det_lam(sums, p)


@njit(cache=True, nogil=True, error_model="numpy")
def keep_best(mean: np.ndarray, cov: np.ndarray, det: np.ndarray, lam: np.ndarray, n_best: int):
    """The ``n_best`` lowest determinants of each group (ties: the earlier start), all groups' in one
    group: mean (1, K, p), covariance (1, K, p, p) and lambda_min estimate (1, K)."""
    g_n, s_n, p = mean.shape
    k_n = min(n_best, s_n)
    out_mean, out_cov, out_lam = np.empty((1, g_n * k_n, p)), np.empty((1, g_n * k_n, p, p)), np.empty((1, g_n * k_n))
    for g in range(g_n):
        order = np.argsort(det[g], kind="mergesort")
        for k in range(k_n):
            out_mean[0, g * k_n + k] = mean[g, order[k]]
            out_cov[0, g * k_n + k] = cov[g, order[k]]
            out_lam[0, g * k_n + k] = lam[g, order[k]]
    return out_mean, out_cov, out_lam


@njit(cache=True, nogil=True, error_model="numpy")
def full_data_stage(mono, mono_t, masks, mean, cov, det, lam, prev, best_det, best_mask, step, iters, h, p, tol2, stepped):
    """FAST-MCD's full-data stage (``measure.mcd``, step 3), C-step ``step`` to ``iters`` - 1 of its
    candidates (``mean``, ``cov``, ``lam``: (1, K, ...)): after each step a candidate whose subset did
    not change has converged (its determinant is final; the lowest such one is the best so far), and of
    candidates on the same subset only one steps on; the lowest determinant after the last step, or of
    the converged ones, wins. ``stepped``: C-step ``step`` was taken already (``masks``.. ``lam`` are its
    results, ``prev`` the masks before it: (1, 0, n) for none). Returns (status, step, masks, mean, cov,
    det, lam, prev, best_det, best_mask): status 1 when C-step ``step`` left a start with lambda_min at
    or below ``tol2`` (the caller looks for an exact fit and, without one, calls again with ``stepped``),
    else 0 and the winner's subset ``best_mask`` (n bools)."""
    while True:
        if not stepped:
            masks, mean, cov, det, lam = few_starts_step(mono, mono_t, mean, cov, lam, h, p)
            for k in range(lam.shape[1]):
                if lam[0, k] <= tol2:
                    return 1, step, masks, mean, cov, det, lam, prev, best_det, best_mask
        stepped = False
        s_n, n = masks.shape[1], masks.shape[2]
        live = np.ones(s_n, np.bool_)
        if prev.shape[1] > 0:
            done = -1
            for k in range(s_n):
                live[k] = False
                for i in range(n):
                    if masks[0, k, i] != prev[0, k, i]:
                        live[k] = True
                        break
                if not live[k] and (done < 0 or det[0, k] < det[0, done]):
                    done = k
            if done >= 0 and det[0, done] < best_det:
                best_det, best_mask = det[0, done], masks[0, done].copy()
        if step == iters - 1:
            # Out of steps: the lowest determinant of all (the converged ones are counted above).
            k = np.argmin(det[0])
            if det[0, k] < best_det:
                best_det, best_mask = det[0, k], masks[0, k].copy()
            return 0, step, masks, mean, cov, det, lam, prev, best_det, best_mask
        order = np.argsort(det[0], kind="mergesort")
        for j in range(1, s_n):
            a, b = order[j], order[j - 1]
            if det[0, a] == det[0, b]:
                same = True
                for i in range(n):
                    if masks[0, a, i] != masks[0, b, i]:
                        same = False
                        break
                if same:
                    live[a] = False
        keep = np.flatnonzero(live)
        if keep.size == 0:
            return 0, step, masks, mean, cov, det, lam, prev, best_det, best_mask
        if keep.size < s_n:
            masks, mean, cov, det, lam = masks[:, keep], mean[:, keep], cov[:, keep], det[:, keep], lam[:, keep]
        prev = masks
        step += 1
