"""Robust range of a short run of pixels: Tukey's bisquare M-estimator of location (docs/method.md step 6)."""

from __future__ import annotations

import math

import numpy as np

TUKEY_C = 4.685  # 95 % efficiency at the normal


def median(values: np.ndarray) -> np.ndarray | float:
    """``np.median`` along the last axis of non-empty, NaN-free ``values`` (any unit).

    The same partition and the same mean of the two middle values as ``np.median``, without its
    generic axis and NaN handling, which costs several times the selection itself on the few
    hundred values of a measurement. Returns a float for 1-D input.
    """
    a = np.asarray(values, dtype=np.float64)
    k = a.shape[-1] // 2
    if a.shape[-1] % 2:
        out = np.partition(a, k, axis=-1)[..., k]
    else:
        part = np.partition(a, (k - 1, k), axis=-1)
        out = (part[..., k - 1] + part[..., k]) / 2.0
    return float(out) if a.ndim == 1 else out


def tukey_scale(values: np.ndarray) -> float:
    """The scale ``tukey_location`` weighs ``values`` (any unit, non-empty) with: 1.4826 MAD, or 1.2533
    times the mean absolute deviation from the median where the MAD is zero (zero: all values equal)."""
    v = np.asarray(values, dtype=np.float64)
    dev = np.abs(v - median(v))
    s = 1.4826 * median(dev)
    return s if s > 0.0 else 1.2533 * float(dev.mean())


def tukey_location(values: np.ndarray, c: float = TUKEY_C, iterations: int = 30) -> tuple[float, float]:
    """Bisquare M-estimate of location of ``values`` (any unit) and its standard error.

    Starts at the median with scale 1.4826 MAD. On quantized data more than half the values
    can be equal, so the MAD is zero: the scale then falls back to 1.2533 times the mean
    absolute deviation from the median (zero only when all values are equal, and then the
    answer is that value). Returns (location, standard error); (NaN, NaN) for no values.
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return math.nan, math.nan
    m = median(v)
    s = tukey_scale(v)
    if s == 0.0:
        return m, 0.0
    cs = c * s
    w = np.empty_like(v)
    for _ in range(iterations):
        # (1 - u²)² for |u| < 1, else 0, with u = (v - m) / cs (1 - u² <= 0 exactly where |u| >= 1).
        np.subtract(v, m, out=w)
        w /= cs
        np.multiply(w, w, out=w)
        np.subtract(1.0, w, out=w)
        np.maximum(w, 0.0, out=w)
        w *= w
        m_new = float((w * v).sum() / w.sum())
        if abs(m_new - m) <= 1e-12 * max(1.0, abs(m)):
            m = m_new
            break
        m = m_new
    u = (v - m) / (c * s)
    inl = np.abs(u) < 1.0
    n_eff = max(1, int(inl.sum()))
    spread = float(np.sqrt(((v[inl] - m) ** 2).mean())) if inl.any() else 0.0
    return m, (spread if spread > 0 else s) / math.sqrt(n_eff)
