"""FAST-MCD's batched concentration step (R&VD section 3), for p = 1, 2, 3 and many starts at once.

``c_step``: Mahalanobis distances of all points to all starts from one matrix product of the
per-point monomials (1, x, y, z, x², xy, ...; ``measure.mcd_kernels.normalised``) with per-start
coefficient rows; the h smallest per start (numpy's partition) form the next subset; its mean and
covariance come from the subset's summed monomials (compiled, ``measure.mcd_kernels.masked_sums``). A
few starts take the whole step in one compiled call. Determinants and adjugates of 1x1, 2x2 and 3x3
covariances are closed form (``det_adj``; per start in ``measure.kernels``). Many starts on many points
are taken in blocks of starts (``_CHUNK_BYTES``), row by row the same numbers. Inputs in
``measure.mcd``'s normalised, dimensionless units.
"""

from __future__ import annotations

import functools

import numpy as np


_FEW_STARTS = 8  # up to this many starts a C-step is one compiled call (measure.mcd_kernels.few_starts_step)
_CHUNK_BYTES = 1 << 18  # a C-step's distances of more than this many bytes are taken in blocks of starts


@functools.lru_cache(maxsize=None)
def pairs(p: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(p)


def det_adj(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form determinant and adjugate of a batch of 1x1, 2x2 or 3x3 symmetric matrices."""
    p = cov.shape[-1]
    adj = np.empty_like(cov)
    if p == 1:
        adj[...] = 1.0
        return cov[..., 0, 0].copy(), adj
    if p == 2:
        a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
        adj[..., 0, 0], adj[..., 1, 1] = d, a
        adj[..., 0, 1] = adj[..., 1, 0] = -b
        return a * d - b * b, adj
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 0, 2]
    e, f, i = cov[..., 1, 1], cov[..., 1, 2], cov[..., 2, 2]
    adj[..., 0, 0] = e * i - f * f
    adj[..., 0, 1] = adj[..., 1, 0] = c * f - b * i
    adj[..., 0, 2] = adj[..., 2, 0] = b * f - c * e
    adj[..., 1, 1] = a * i - c * c
    adj[..., 1, 2] = adj[..., 2, 1] = b * c - a * f
    adj[..., 2, 2] = a * e - b * b
    return a * adj[..., 0, 0] + b * adj[..., 0, 1] + c * adj[..., 0, 2], adj


def mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b with a (..., S, K), b (..., K, N), as a stack of small products.

    OpenBLAS hands a gemm of more than 4 x 65536 multiply-adds (its GEMM_MULTITHREAD_THRESHOLD
    x SMP_THRESHOLD_MIN) to several threads; on a busy machine that hand-off costs 10-100x the
    arithmetic (measured: 20 ms instead of 0.2 ms for 500 x 9 x 300). Chunks of the S rows
    below that size stay single-threaded, and as few chunks as possible keep numpy's per-call
    overhead down.
    """
    s, k, n = a.shape[-2], a.shape[-1], b.shape[-1]
    c = max(1, 250_000 // max(1, k * n))
    if c >= s:
        return a @ b
    return np.concatenate([a[..., i : i + c, :] @ b for i in range(0, s, c)], axis=-2)


def c_step(mono: np.ndarray, mono_t: np.ndarray, mean: np.ndarray, cov: np.ndarray, lam: np.ndarray, h: int, p: int):
    """One concentration step for G groups of S starts on G point sets (monomials G x n x m, and
    ``mono_t`` the same as G x m x n).

    ``mean`` is G x S x p, ``cov`` G x S x p x p, ``lam`` their lambda_min estimates (G x S). Returns
    the new subset masks (G x S x n), means, covariances, determinants and lambda_min estimates (each
    G x S ...). The per-start arithmetic, the masks and the sums are compiled (``measure.kernels``,
    ``measure.mcd_kernels``); the distances' matrix product stays with BLAS and the selection with
    numpy's partition (SIMD, faster than a loop).
    """
    from measure.compiled import few_starts_step, masked_sums, moments_det_lam, start_coefficients  # loaded on first use: `import measure` stays fast

    g_n, starts = mean.shape[:2]
    if mono.dtype == np.float64 and g_n * starts <= _FEW_STARTS:
        # A few starts (the full data's best five): the whole step in one compiled call (the numpy calls
        # cost more than their arithmetic).
        return few_starts_step(mono, mono_t, mean, cov, lam, h, p)
    coef = start_coefficients(mean, cov, lam).astype(mono.dtype, copy=False)
    n = mono.shape[1]
    mask, sums = np.empty((g_n, starts, n), bool), np.empty((g_n, starts, mono.shape[2]))
    parts = min(starts, -(-g_n * starts * n * mono.itemsize // _CHUNK_BYTES))
    # Long segments: the starts in blocks, each block's distances, selection and sums before the next
    # block's (the same numbers, row by row). One array of all the distances is larger than the C
    # library's allocator keeps mapped between calls: every C-step paid its page faults (434 vs 204 us
    # for 104 starts on 480 points).
    rows = -(-starts // parts)
    for i in range(0, starts, rows):
        d2 = mm(coef[:, i : i + rows], mono_t)
        masked_sums(*_h_smallest(d2, h), mono_t, i, mask, sums)
    return (mask,) + moments_det_lam(sums, p)


def _h_smallest(d2: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Per start (last axis: the points' d² >= 0), the bit patterns of the d² and the h-th smallest of
    them: the points at or below it are the ``h`` smallest (with any ties at the h-th).

    The bit patterns of non-negative floats read as integers sort like the floats, and an integer
    partition skips the NaN-aware float comparisons. Double-precision d² is selected on its own 64-bit
    patterns: a partition of those costs less than rounding them to single precision and partitioning
    32-bit ones (59 vs 16 + 49 us for 104 starts of 270 points), and needs no second selection where
    rounding joins values at the h-th (common on quantized disparities)."""
    key = d2.view(np.int32 if d2.dtype == np.float32 else np.int64)
    # Expanded in monomials, d² of a point on the start's support can round a hair below zero: a negative
    # float's pattern is a negative integer, clamped to 0 (the pattern of +0.0), as max(d², 0) would.
    np.maximum(key, 0, out=key)
    return key, np.partition(key, h - 1, axis=-1)[..., h - 1]
