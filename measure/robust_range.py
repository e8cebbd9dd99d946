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
    if a.ndim == 1 and a.size:
        # One compiled selection: numpy's partition and mean cost several times its work on a few values.
        from measure.compiled import median_1d  # loaded on first use: `import measure` stays fast

        return float(median_1d(np.ascontiguousarray(a)))
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
    from measure.compiled import bisquare_location  # loaded on first use: `import measure` stays fast

    # The iterations, (1 - u²)² for |u| < 1, else 0, with u = (v - m) / (c s), in one compiled loop.
    return bisquare_location(np.ascontiguousarray(v), float(m), float(c), float(s), int(iterations))
