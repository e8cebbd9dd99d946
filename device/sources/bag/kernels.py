"""The bag source's compiled loops (numba), where numpy has no one-pass form: the z-buffered
footprint splat behind ``geometry.align_depth_to_color`` and depth pixels to disparity.

Splat, per valid depth pixel: back-project its footprint corners (+-0.5 px) and centre at its depth,
move them by ``p_c = R p_d + t``, project with the colour intrinsics, round to the colour pixels whose
centres the footprint holds (at most ``max_splat`` per axis) and keep the nearest ``Z`` per colour
pixel; a footprint holding no centre offers its centre's pixel as a fallback, used where no footprint
holds that centre. The arithmetic is float64 in the order the vectorised numpy formulation used, so
the rounding decisions and the values are the same bit for bit (tests/device/test_bag_kernels.py); the
buffer is float32 (rounding to float32 keeps order, so the nearest is the same). Compiled on first use
and cached on disk (numba ``cache=True``). Why compiled loops: docs/decisions/bag-source.md ("Speed").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def _to_color(xn: float, yn: float, z: float, R: np.ndarray, t: np.ndarray) -> tuple[float, float, float]:
    """A depth-camera ray ``(xn, yn, 1)`` at depth ``z`` -> the point in the colour camera (metres)."""
    x = xn * z
    y = yn * z
    return (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0], R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1],
            R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2])  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy")
def splat_nearest(z_d: np.ndarray, xn: np.ndarray, yn: np.ndarray, R: np.ndarray, t: np.ndarray, c: np.ndarray, width: int,
                  height: int, max_splat: int, k: float, unit: float) -> np.ndarray:  # fmt: skip
    """Depth ``z_d`` (H x W, metres, or depth units of ``unit`` m when ``unit`` > 0: then each is
    ``float32(z) * float32(unit)`` first; not > 0 or not finite = none) -> the colour camera's ``Z``
    (height x width float32, NaN = none), or ``k / Z`` in float32 when ``k`` > 0 (disparity: ``k = fx * B``).
    ``xn`` (3 x W) and ``yn`` (3 x H): the depth camera's normalised ray coordinates ``(u + o - cx) / fx``
    of each column and row at the offsets o = -0.5, +0.5, 0; ``R``, ``t``: depth to colour (metres);
    ``c``: the colour camera's (fx, fy, cx, cy).

    Steps per depth row: the footprints' corner pixels and centre depth without branches (the compiler
    vectorises it), then per valid pixel the rounding fallback, the bounds and the z-buffer writes."""
    # One buffer: inf = empty, a positive value = the nearest footprint holding the centre, a negative
    # value = minus the nearest fallback (any footprint holding the centre replaces it).
    buf = np.full(height * width, np.inf, np.float32)
    n = z_d.shape[1]
    span = np.empty((4, n), np.int64)  # first and end column, first and end row of each footprint (clipped)
    key = np.empty(n, np.float32)  # Z, negative for a fallback
    unit32 = np.float32(unit)
    for v in range(z_d.shape[0]):
        for u in range(n):
            z = np.float64(np.float32(z_d[v, u]) * unit32) if unit > 0 else np.float64(z_d[v, u])
            X, Y, Z = _to_color(xn[0, u], yn[0, v], z, R, t)
            xa, ya = c[0] * X / Z + c[2], c[1] * Y / Z + c[3]
            X, Y, Z = _to_color(xn[1, u], yn[1, v], z, R, t)
            xb, yb = c[0] * X / Z + c[2], c[1] * Y / Z + c[3]
            X, Y, zc = _to_color(xn[2, u], yn[2, v], z, R, t)
            # the colour pixels whose centres lie in [min, max) per axis (NaN stays NaN: dropped below)
            x0, x1 = np.ceil(_nan_min(xa, xb)), np.ceil(_nan_max(xa, xb)) - 1.0
            y0, y1 = np.ceil(_nan_min(ya, yb)), np.ceil(_nan_max(ya, yb)) - 1.0
            primary = (x1 >= x0) & (y1 >= y0)
            # no centre across an axis: the pixel under the footprint's centre there
            xm, ym = np.floor(c[0] * X / zc + c[2] + 0.5), np.floor(c[1] * Y / zc + c[3] + 0.5)
            x0, x1 = (xm, xm) if x1 < x0 else (x0, x1)
            y0, y1 = (ym, ym) if y1 < y0 else (y0, y1)
            ok = (z > 0.0) & math.isfinite(z) & (zc > 0.0) & math.isfinite(x0 + x1 + y0 + y1)
            ok &= (x1 >= 0.0) & (x0 <= width - 1) & (y1 >= 0.0) & (y0 <= height - 1)
            # clipped to the image in float64 before any integer conversion (a corner may be far outside)
            span[0, u] = int(max(x0, 0.0)) if ok else 0
            span[1, u] = int(min(max(x0 + min(x1 - x0 + 1.0, max_splat), 0.0), width)) if ok else 0
            span[2, u] = int(max(y0, 0.0)) if ok else 0
            span[3, u] = int(min(max(y0 + min(y1 - y0 + 1.0, max_splat), 0.0), height)) if ok else 0
            key[u] = np.float32(zc) if primary else -np.float32(zc)
        for u in range(n):
            z32 = key[u]
            for ys in range(span[2, u], span[3, u]):
                for i in range(ys * width + span[0, u], ys * width + span[1, u]):
                    b = buf[i]
                    if z32 > 0:
                        if b < 0 or z32 < b:
                            buf[i] = z32
                    elif b == np.inf or (b < 0 and z32 > b):
                        buf[i] = z32
    for i in range(height * width):  # empty -> NaN, a fallback -> its depth
        buf[i] = np.float32(np.nan) if buf[i] == np.inf else abs(buf[i])
    if k > 0:
        np.divide(np.float32(k), buf, buf)
    return buf.reshape(height, width)


@njit(cache=True, nogil=True)
def _nan_min(a: float, b: float) -> float:
    return a if (a <= b) | math.isnan(a) else b


@njit(cache=True, nogil=True)
def _nan_max(a: float, b: float) -> float:
    return a if (a >= b) | math.isnan(a) else b


@njit(cache=True, nogil=True, error_model="numpy")
def disparity_from_pixels(px: np.ndarray, k: float) -> np.ndarray:
    """Depth pixels (uint16 units or float32 metres, any shape) -> ``k / depth`` in float32 (the
    division of float32 values), NaN where the pixel is no depth (0, NaN, negative): one pass."""
    k32 = np.float32(k)
    flat = px.ravel()
    out = np.empty(flat.size, np.float32)
    for i in range(flat.size):
        z = np.float32(flat[i])
        out[i] = k32 / z if z > 0 else np.float32(np.nan)
    return out.reshape(px.shape)
