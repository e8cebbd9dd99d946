"""The bag source's compiled loops (numba), where numpy has no one-pass form: the z-buffered
footprint splat behind ``geometry.align_depth_to_color`` and depth pixels to disparity.

Splat, per valid depth pixel: back-project its footprint corners (+-0.5 px) and centre at its depth,
move them into the colour camera, project with the colour intrinsics, round to the colour pixels whose
centres the footprint holds (at most ``max_splat`` per axis) and keep the nearest ``Z`` per colour
pixel; a footprint holding no centre on an axis offers the pixel under its centre there as a
fallback, used where no footprint holds that centre. Arithmetic: float32, in a fixed order that the
numpy formulation of tests/device/test_bag_kernels.py repeats, so the rounding decisions and the
values are the same bit for bit; each ray's direction in the colour camera, ``R (xn, yn, 1)``, is a
column term plus a row term computed once per image (``ray_terms``). Steps per depth row: ``_row``
computes every pixel's clipped footprint and stored value without branches (the compiler vectorises
it), then the z-buffer writes, a select rather than a branch (contention outliers make the
nearer-or-not test a coin toss) and straight-line code for the usual 2 x 2 footprint; the rare
fallbacks are recomputed one by one (``_fallback``). The buffer holds the output value itself
(``Z``, or the float32 disparity ``k / Z``, which orders the same way reversed), NaN = empty,
negative = a fallback, made positive at the end from the list of the places written; so no pass over
the whole image follows the splat. Compiled on first use and cached on disk (numba ``cache=True``).
Why compiled loops and float32: docs/decisions/bag-source.md ("Speed").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_JIT = dict(cache=True, nogil=True, error_model="numpy")
OFFSETS = (-0.5, 0.5, 0.0)  # footprint corners and centre, depth pixels


def ray_terms(R: np.ndarray, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each depth ray ``(xn, yn, 1)`` rotated into the colour camera, split as column term + row term:
    ``cols[o] = R[:, 0] xn[o] + R[:, 2]`` (3 x 3 x W) and ``rows[o] = R[:, 1] yn[o]`` (3 x 3 x H), float64
    rounded to float32; ``xn`` (3 x W) and ``yn`` (3 x H) are the normalised coordinates at ``OFFSETS``."""
    R = np.asarray(R, np.float64)
    cols = R[None, :, 0, None] * xn[:, None, :] + R[None, :, 2, None]
    rows = R[None, :, 1, None] * yn[:, None, :]
    return np.ascontiguousarray(cols, np.float32), np.ascontiguousarray(rows, np.float32)


@njit(cache=True, nogil=True)
def _nan_min(a: float, b: float) -> float:
    return a if (a <= b) | math.isnan(a) else b


@njit(cache=True, nogil=True)
def _nan_max(a: float, b: float) -> float:
    return a if (a >= b) | math.isnan(a) else b


@njit(**_JIT)
def _depth(z_d: np.ndarray, v: int, u: int, unit: np.float32) -> np.float32:
    """Depth pixel (v, u) in metres, float32: ``float32(code) * float32(unit)`` for units (``unit`` > 0)."""
    return np.float32(z_d[v, u]) * unit if unit > 0 else np.float32(z_d[v, u])


@njit(**_JIT)
def _project(z: np.float32, cols: np.ndarray, rows: np.ndarray, o: int, u: int, v: int, t: np.ndarray,
             c: np.ndarray) -> tuple[np.float32, np.float32, np.float32]:  # fmt: skip
    """Depth pixel (v, u) at depth ``z`` and offset ``o`` -> colour pixel coordinates (x, y) and ``Z`` (m)."""
    Z = z * (cols[o, 2, u] + rows[o, 2, v]) + t[2]
    x = c[0] * (z * (cols[o, 0, u] + rows[o, 0, v]) + t[0]) / Z + c[2]
    y = c[1] * (z * (cols[o, 1, u] + rows[o, 1, v]) + t[1]) / Z + c[3]
    return x, y, Z


@njit(**_JIT)
def _centres(z: np.float32, cols: np.ndarray, rows: np.ndarray, u: int, v: int, t: np.ndarray,
             c: np.ndarray) -> tuple[np.float32, np.float32, np.float32, np.float32]:  # fmt: skip
    """First and last colour pixel column and row whose centres the footprint of (v, u) at ``z`` holds
    (last < first on an axis where it holds none; NaN where a corner does not project)."""
    one = np.float32(1.0)
    xa, ya, _ = _project(z, cols, rows, 0, u, v, t, c)
    xb, yb, _ = _project(z, cols, rows, 1, u, v, t, c)
    return np.ceil(_nan_min(xa, xb)), np.ceil(_nan_max(xa, xb)) - one, np.ceil(_nan_min(ya, yb)), np.ceil(_nan_max(ya, yb)) - one


@njit(**_JIT)
def _row(z_d: np.ndarray, v: int, cols: np.ndarray, rows: np.ndarray, t: np.ndarray, c: np.ndarray, unit: np.float32,
         k: np.float32, width: int, height: int, max_splat: int, span: np.ndarray, val: np.ndarray) -> None:  # fmt: skip
    """Depth row ``v``: each pixel's clipped colour span (first and end column, first and end row; empty
    where it writes nothing) and its value, negative for a fallback (0 where the depth is none)."""
    zero, one = np.float32(0.0), np.float32(1.0)
    wf, hf, ms = np.float32(width), np.float32(height), np.float32(max_splat)
    for u in range(z_d.shape[1]):
        z = _depth(z_d, v, u, unit)
        x0, x1, y0, y1 = _centres(z, cols, rows, u, v, t, c)
        zc = z * (cols[2, 2, u] + rows[2, 2, v]) + t[2]
        live = (z > zero) & (z < np.inf) & (zc > zero)
        primary = (x1 >= x0) & (y1 >= y0)
        # NaN compares false, so a corner that does not project leaves the span empty
        ok = live & primary & (x1 >= zero) & (x0 <= wf - one) & (y1 >= zero) & (y0 <= hf - one)
        ok &= (x0 > -np.inf) & (x1 < np.inf) & (y0 > -np.inf) & (y1 < np.inf)
        # clipped to the image before the integer conversion (a corner may be far outside)
        span[0, u] = np.int32(max(x0, zero) if ok else zero)
        span[1, u] = np.int32(min(max(x0 + min(x1 - x0 + one, ms), zero), wf) if ok else zero)
        span[2, u] = np.int32(max(y0, zero) if ok else zero)
        span[3, u] = np.int32(min(max(y0 + min(y1 - y0 + one, ms), zero), hf) if ok else zero)
        s = k / zc if k > zero else zc
        val[u] = (s if primary else -s) if live else zero


@njit(**_JIT)
def _fallback(buf: np.ndarray, z_d: np.ndarray, v: int, u: int, cols: np.ndarray, rows: np.ndarray, t: np.ndarray,
              c: np.ndarray, unit: np.float32, width: int, height: int, max_splat: int, s: np.float32, sign: np.float32,
              written: np.ndarray, n: int) -> tuple[np.ndarray, int]:  # fmt: skip
    """Depth pixel (v, u)'s fallback (value ``s``): the pixel under its centre on each axis its footprint
    holds no centre on; written as ``-s`` where empty or a farther fallback. The places written are
    appended to ``written`` (grown as needed); returns it and its new length."""
    z = _depth(z_d, v, u, unit)
    x0, x1, y0, y1 = _centres(z, cols, rows, u, v, t, c)
    xc, yc, _ = _project(z, cols, rows, 2, u, v, t, c)
    half = np.float32(0.5)
    xm, ym = np.floor(xc + half), np.floor(yc + half)
    x0, x1 = (xm, xm) if x1 < x0 else (x0, x1)
    y0, y1 = (ym, ym) if y1 < y0 else (y0, y1)
    if not (math.isfinite(x0 + x1 + y0 + y1) and x1 >= 0.0 and x0 <= width - 1 and y1 >= 0.0 and y0 <= height - 1):
        return written, n
    xs, xe = int(max(x0, 0.0)), int(min(max(x0 + min(x1 - x0 + 1.0, max_splat), 0.0), width))
    for ys in range(int(max(y0, 0.0)), int(min(max(y0 + min(y1 - y0 + 1.0, max_splat), 0.0), height))):
        for i in range(ys * width + xs, ys * width + xe):
            b = buf[i]
            if b != b or (b < 0 and s * sign > -b * sign):
                buf[i] = -s
                if n == written.size:
                    written = np.concatenate((written, np.empty(n, np.int64)))
                written[n] = i
                n += 1
    return written, n


@njit(**_JIT)
def _put(buf: np.ndarray, i: int, s: np.float32, ss: np.float32, sign: np.float32) -> None:
    """A footprint holding pixel ``i``'s centre replaces an empty pixel, a fallback or a farther one
    (``ss = s * sign``; sign +1 for disparity, -1 for Z)."""
    b = buf[i]
    buf[i] = s if (not (b > 0)) | (ss > b * sign) else b


@njit(**_JIT)
def splat_nearest(z_d: np.ndarray, cols: np.ndarray, rows: np.ndarray, t: np.ndarray, c: np.ndarray, width: int,
                  height: int, max_splat: int, k: float, unit: float) -> np.ndarray:  # fmt: skip
    """Depth ``z_d`` (H x W, metres, or depth units of ``unit`` m when ``unit`` > 0: then each is
    ``float32(z) * float32(unit)`` first; not > 0 or not finite = none) -> the colour camera's ``Z``
    (height x width float32, NaN = none), or ``k / Z`` in float32 when ``k`` > 0 (disparity: ``k = fx * B``).
    ``cols``, ``rows``: ``ray_terms`` of the depth camera and the rotation depth -> colour (float32);
    ``t``: the translation depth -> colour (m, float32); ``c``: the colour camera's (fx, fy, cx, cy), float32."""
    buf = np.full(height * width, np.nan, np.float32)
    n = z_d.shape[1]
    span = np.empty((4, n), np.int32)
    val = np.empty(n, np.float32)
    written = np.empty(1024, np.int64)  # where fallbacks were written
    n_written = 0
    k32, unit32 = np.float32(k), np.float32(unit)
    sign = np.float32(1.0) if k > 0 else np.float32(-1.0)
    for v in range(z_d.shape[0]):
        _row(z_d, v, cols, rows, t, c, unit32, k32, width, height, max_splat, span, val)
        for u in range(n):
            s = val[u]
            if s < 0:
                written, n_written = _fallback(buf, z_d, v, u, cols, rows, t, c, unit32, width, height, max_splat, -s, sign,
                                               written, n_written)  # fmt: skip
                continue
            x0, x1, y0, y1 = span[0, u], span[1, u], span[2, u], span[3, u]
            ss = s * sign
            if x1 - x0 == 2 and y1 - y0 == 2:  # a half-resolution depth pixel's usual footprint
                i = y0 * width + x0
                _put(buf, i, s, ss, sign)
                _put(buf, i + 1, s, ss, sign)
                _put(buf, i + width, s, ss, sign)
                _put(buf, i + width + 1, s, ss, sign)
                continue
            for ys in range(y0, y1):
                for i in range(ys * width + x0, ys * width + x1):
                    _put(buf, i, s, ss, sign)
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
