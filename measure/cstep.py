"""FAST-MCD's batched concentration step (R&VD section 3), for p = 1, 2, 3 and many starts at once.

``c_step``: Mahalanobis distances of all points to all starts from one matrix product of the
per-point ``monomials`` (1, x, y, z, x², xy, ...) with per-start coefficient rows; the h smallest per
start form the next subset; its mean and covariance come from one more matrix product of the subset
mask with the monomials. Determinants and adjugates of 1x1, 2x2 and 3x3 covariances are closed form
(``det_adj``; per start in ``measure.kernels``). Many starts on many points are taken in blocks of
starts (``_CHUNK_BYTES``), row by row the same numbers. Inputs in ``measure.mcd``'s normalised,
dimensionless units.
"""

from __future__ import annotations

import functools

import numpy as np


_FEW_STARTS = 8  # up to this many starts a C-step's masks come from one compiled call (measure.fit_kernels)
_CHUNK_BYTES = 1 << 18  # a C-step's distances of more than this many bytes are taken in blocks of starts


@functools.lru_cache(maxsize=None)
def pairs(p: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(p)


def monomials(z: np.ndarray) -> np.ndarray:
    """Per point: (1, z_1..z_p, z_j z_k for j <= k); n x m. The leading 1 makes one matrix
    product give a subset's count and a start's constant term."""
    j, k = pairs(z.shape[1])
    return np.concatenate([np.ones((len(z), 1)), z, z[:, j] * z[:, k]], axis=1)


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


def c_step(mono: np.ndarray, mean: np.ndarray, cov: np.ndarray, lam: np.ndarray, h: int, p: int):
    """One concentration step for G groups of S starts on G point sets (monomials G x n x m).

    ``mean`` is G x S x p, ``cov`` G x S x p x p, ``lam`` their lambda_min estimates (G x S). Returns
    the new subset masks (G x S x n), means, covariances, determinants and lambda_min estimates (each
    G x S ...). The per-start arithmetic and the moments are compiled (``measure.kernels``); the two
    matrix products stay with BLAS and the selection with numpy's partition (SIMD, faster than a loop).
    """
    from measure.kernels import moments_det_lam, start_coefficients  # numba loads on first use: `import measure` stays fast
    if mono.dtype == np.float64 and mean.shape[0] * mean.shape[1] <= _FEW_STARTS:
        # A few starts (the full data's best five): the masks in one compiled call (the numpy calls
        # cost more than their arithmetic), the sums by the same BLAS product.
        from measure.fit_kernels import few_starts_masks

        mask = few_starts_masks(np.ascontiguousarray(mono), mean, cov, lam, h)
        return (mask,) + moments_det_lam(mm(mask.astype(np.float64), mono), p)
    coef = start_coefficients(mean, cov, lam).astype(mono.dtype, copy=False)
    starts = coef.shape[1]
    parts = min(starts, -(-coef.shape[0] * starts * mono.shape[1] * mono.itemsize // _CHUNK_BYTES))
    if parts > 1:
        # Long segments: the starts in blocks, each block's distances, selection and sums before the
        # next block's (the same numbers, row by row). One array of all the distances is larger than
        # the C library's allocator keeps mapped between calls: every C-step paid its page faults
        # (434 vs 204 us for 104 starts on 480 points).
        rows = -(-starts // parts)
        blocks = [_selected(coef[:, i : i + rows], mono, h) for i in range(0, starts, rows)]
        mask, sums = np.concatenate([b[0] for b in blocks], axis=1), np.concatenate([b[1] for b in blocks], axis=1)
    else:
        mask, sums = _selected(coef, mono, h)
    return (mask,) + moments_det_lam(sums.astype(np.float64, copy=False), p)


def _selected(coef: np.ndarray, mono: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """The masks and summed monomials of the ``h`` points nearest each start (coefficient rows ``coef``)."""
    d2 = mm(coef, np.swapaxes(mono, -1, -2))
    # Expanded in monomials, d² of a point on the start's support can round a hair below zero.
    np.maximum(d2, 0.0, out=d2)
    return _h_smallest(d2, h, mono)


def _h_smallest(d2: np.ndarray, h: int, mono: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per start (last axis: the points' d² >= 0), the mask of the ``h`` smallest (with any ties at the
    h-th) and the summed monomials of those points.

    The bit patterns of non-negative floats read as integers sort like the floats, and an integer
    partition skips the NaN-aware float comparisons. Double-precision d² is selected on its own 64-bit
    patterns: a partition of those costs less than rounding them to single precision and partitioning
    32-bit ones (59 vs 16 + 49 us for 104 starts of 270 points), and needs no second selection where
    rounding joins values at the h-th (common on quantized disparities)."""
    key = d2.view(np.int32 if d2.dtype == np.float32 else np.int64)
    mask = key <= np.partition(key, h - 1, axis=-1)[..., h - 1 : h]
    return mask, mm(mask.astype(mono.dtype), mono)
