"""The bag source's compiled loops (numba), where numpy has no one-pass form: the z-buffered
footprint splat behind ``geometry.align_depth_to_color`` and depth pixels to disparity.

Splat, per valid depth pixel: back-project its footprint corners (+-0.5 px) and centre at its depth,
move them by ``p_c = R p_d + t``, project with the colour intrinsics, round to the colour pixels whose
centres the footprint holds (at most ``max_splat`` per axis) and keep the nearest ``Z`` per colour
pixel; a footprint holding no centre on an axis offers the pixel under its centre there as a
fallback, used where no footprint holds that centre. The arithmetic is float64 in the order the
vectorised numpy formulation used, so the rounding decisions and the values are the same bit for bit
(tests/device/test_bag_kernels.py). Steps per depth row: ``_row`` computes every pixel's clipped
footprint and stored value without branches (the compiler vectorises it), then the z-buffer writes;
the rare fallbacks are recomputed one by one (``_fallback``). The buffer holds the output value
itself (``Z``, or the float32 disparity ``k / Z``, which orders the same way reversed), NaN = empty,
negative = a fallback, made positive at the end from the list of the places written; so no pass over
the whole image follows the splat. Compiled on first use and cached on disk (numba ``cache=True``).
Why compiled loops: docs/decisions/bag-source.md ("Speed").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_JIT = dict(cache=True, nogil=True, error_model="numpy")


@njit(**_JIT)
def _to_color(xn: float, yn: float, z: float, R: np.ndarray, t: np.ndarray) -> tuple[float, float, float]:
    """A depth-camera ray ``(xn, yn, 1)`` at depth ``z`` -> the point in the colour camera (metres)."""
    x = xn * z
    y = yn * z
    return (R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0], R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1],
            R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2])  # fmt: skip


@njit(cache=True, nogil=True)
def _nan_min(a: float, b: float) -> float:
    return a if (a <= b) | math.isnan(a) else b


@njit(cache=True, nogil=True)
def _nan_max(a: float, b: float) -> float:
    return a if (a >= b) | math.isnan(a) else b


@njit(**_JIT)
def _depth(z_d: np.ndarray, v: int, u: int, unit: float, unit32: np.float32) -> float:
    """Depth pixel (v, u) in metres: ``float32(code) * float32(unit)`` for units (``unit`` > 0)."""
    return np.float64(np.float32(z_d[v, u]) * unit32) if unit > 0 else np.float64(z_d[v, u])


@njit(**_JIT)
def _centres(z: float, xn: np.ndarray, yn: np.ndarray, u: int, v: int, R: np.ndarray, t: np.ndarray,
             c: np.ndarray) -> tuple[float, float, float, float]:  # fmt: skip
    """First and last colour pixel column and row whose centres the footprint of (v, u) at ``z`` holds
    (last < first on an axis where it holds none; NaN where a corner does not project)."""
    X, Y, Z = _to_color(xn[0, u], yn[0, v], z, R, t)
    xa, ya = c[0] * X / Z + c[2], c[1] * Y / Z + c[3]
    X, Y, Z = _to_color(xn[1, u], yn[1, v], z, R, t)
    xb, yb = c[0] * X / Z + c[2], c[1] * Y / Z + c[3]
    return np.ceil(_nan_min(xa, xb)), np.ceil(_nan_max(xa, xb)) - 1.0, np.ceil(_nan_min(ya, yb)), np.ceil(_nan_max(ya, yb)) - 1.0


@njit(**_JIT)
def _row(z_d: np.ndarray, v: int, xn: np.ndarray, yn: np.ndarray, R: np.ndarray, t: np.ndarray, c: np.ndarray, unit: float,
         k: float, width: int, height: int, max_splat: int, span: np.ndarray, val: np.ndarray) -> None:  # fmt: skip
    """Depth row ``v``: each pixel's clipped colour span (first and end column, first and end row; empty
    where it writes nothing) and its value, negative for a fallback (0 where the depth is none)."""
    unit32, k32 = np.float32(unit), np.float32(k)
    wf, hf, ms = np.float64(width), np.float64(height), np.float64(max_splat)
    for u in range(z_d.shape[1]):
        z = _depth(z_d, v, u, unit, unit32)
        x0, x1, y0, y1 = _centres(z, xn, yn, u, v, R, t, c)
        zc = _to_color(xn[2, u], yn[2, v], z, R, t)[2]
        live = (z > 0.0) & (z < np.inf) & (zc > 0.0)
        primary = (x1 >= x0) & (y1 >= y0)
        # NaN compares false, so a corner that does not project leaves the span empty
        ok = live & primary & (x1 >= 0.0) & (x0 <= wf - 1.0) & (y1 >= 0.0) & (y0 <= hf - 1.0)
        ok &= (x0 > -np.inf) & (x1 < np.inf) & (y0 > -np.inf) & (y1 < np.inf)
        # clipped to the image in float64 before the integer conversion (a corner may be far outside)
        span[0, u] = np.int32(max(x0, 0.0) if ok else 0.0)
        span[1, u] = np.int32(min(max(x0 + min(x1 - x0 + 1.0, ms), 0.0), wf) if ok else 0.0)
        span[2, u] = np.int32(max(y0, 0.0) if ok else 0.0)
        span[3, u] = np.int32(min(max(y0 + min(y1 - y0 + 1.0, ms), 0.0), hf) if ok else 0.0)
        s = k32 / np.float32(zc) if k > 0 else np.float32(zc)
        val[u] = (s if primary else -s) if live else np.float32(0.0)


@njit(**_JIT)
def _nearer(s: float, b: float, disparity: bool) -> bool:
    return s > b if disparity else s < b


@njit(**_JIT)
def _fallback(buf: np.ndarray, z_d: np.ndarray, v: int, u: int, xn: np.ndarray, yn: np.ndarray, R: np.ndarray, t: np.ndarray,
              c: np.ndarray, unit: float, width: int, height: int, max_splat: int, s: float, disparity: bool,
              written: np.ndarray, n: int) -> tuple[np.ndarray, int]:  # fmt: skip
    """Depth pixel (v, u)'s fallback (value ``s``): the pixel under its centre on each axis its footprint
    holds no centre on; written as ``-s`` where empty or a farther fallback. The places written are
    appended to ``written`` (grown as needed); returns it and its new length."""
    z = _depth(z_d, v, u, unit, np.float32(unit))
    x0, x1, y0, y1 = _centres(z, xn, yn, u, v, R, t, c)
    X, Y, zc = _to_color(xn[2, u], yn[2, v], z, R, t)
    xm, ym = np.floor(c[0] * X / zc + c[2] + 0.5), np.floor(c[1] * Y / zc + c[3] + 0.5)
    x0, x1 = (xm, xm) if x1 < x0 else (x0, x1)
    y0, y1 = (ym, ym) if y1 < y0 else (y0, y1)
    if not (math.isfinite(x0 + x1 + y0 + y1) and x1 >= 0.0 and x0 <= width - 1 and y1 >= 0.0 and y0 <= height - 1):
        return written, n
    xs, xe = int(max(x0, 0.0)), int(min(max(x0 + min(x1 - x0 + 1.0, max_splat), 0.0), width))
    for ys in range(int(max(y0, 0.0)), int(min(max(y0 + min(y1 - y0 + 1.0, max_splat), 0.0), height))):
        for i in range(ys * width + xs, ys * width + xe):
            b = buf[i]
            if b != b or (b < 0 and _nearer(s, -b, disparity)):
                buf[i] = -s
                if n == written.size:
                    written = np.concatenate((written, np.empty(n, np.int64)))
                written[n] = i
                n += 1
    return written, n


@njit(**_JIT)
def _put(buf: np.ndarray, i: int, s: float, disparity: bool) -> None:
    """A footprint holding pixel ``i``'s centre: it replaces an empty pixel, a fallback or a farther one."""
    b = buf[i]
    if not (b > 0) or _nearer(s, b, disparity):
        buf[i] = s


@njit(**_JIT)
def splat_nearest(z_d: np.ndarray, xn: np.ndarray, yn: np.ndarray, R: np.ndarray, t: np.ndarray, c: np.ndarray, width: int,
                  height: int, max_splat: int, k: float, unit: float) -> np.ndarray:  # fmt: skip
    """Depth ``z_d`` (H x W, metres, or depth units of ``unit`` m when ``unit`` > 0: then each is
    ``float32(z) * float32(unit)`` first; not > 0 or not finite = none) -> the colour camera's ``Z``
    (height x width float32, NaN = none), or ``k / Z`` in float32 when ``k`` > 0 (disparity: ``k = fx * B``).
    ``xn`` (3 x W) and ``yn`` (3 x H): the depth camera's normalised ray coordinates ``(u + o - cx) / fx``
    of each column and row at the offsets o = -0.5, +0.5, 0; ``R``, ``t``: depth to colour (metres);
    ``c``: the colour camera's (fx, fy, cx, cy)."""
    buf = np.full(height * width, np.nan, np.float32)
    n = z_d.shape[1]
    span = np.empty((4, n), np.int32)
    val = np.empty(n, np.float32)
    written = np.empty(1024, np.int64)  # where fallbacks were written
    n_written = 0
    disparity = k > 0
    for v in range(z_d.shape[0]):
        _row(z_d, v, xn, yn, R, t, c, unit, k, width, height, max_splat, span, val)
        for u in range(n):
            s = val[u]
            if s < 0:
                written, n_written = _fallback(buf, z_d, v, u, xn, yn, R, t, c, unit, width, height, max_splat, -s, disparity,
                                               written, n_written)  # fmt: skip
                continue
            x0, w = span[0, u], span[1, u] - span[0, u]
            if w <= 0:
                continue
            for ys in range(span[2, u], span[3, u]):  # most footprints hold 1-3 centres a row: no inner loop for 1 or 2
                i = ys * width + x0
                _put(buf, i, s, disparity)
                if w > 1:
                    _put(buf, i + 1, s, disparity)
                    for j in range(2, w):
                        _put(buf, i + j, s, disparity)
    for j in range(n_written):
        buf[written[j]] = abs(buf[written[j]])
    return buf.reshape(height, width)


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
