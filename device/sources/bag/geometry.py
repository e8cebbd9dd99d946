"""Bag geometry: rigid transforms, depth-to-colour registration and time pairing.

Units: metres for points and depth, pixels for images, nanoseconds for times. ``align_depth_to_color``
splats each depth pixel's footprint into the colour camera with a z-buffer (the measured reasons for its
footprint rule: docs/decisions/bag-source.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from measure import PinholeCamera

from device.sources.bag.errors import BagError

MAX_SPLAT_PX = 8  # a depth pixel covers at most this many colour pixels per axis (grazing surfaces)


@dataclass(frozen=True)
class Rigid:
    """``p_to = R @ p_from + t`` (metres)."""

    R: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    t: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def from_arrays(cls, R: np.ndarray, t: np.ndarray) -> Rigid:
        return cls(tuple(tuple(float(v) for v in row) for row in np.asarray(R, float)), tuple(float(v) for v in np.asarray(t, float)))  # type: ignore[arg-type]

    @classmethod
    def from_msg(cls, transform: Any) -> Rigid:
        """From a geometry_msgs/Transform (quaternion x, y, z, w)."""
        q = transform.rotation
        x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
        n = math.sqrt(x * x + y * y + z * z + w * w)
        if not n > 0:
            raise BagError("a recorded transform has a zero quaternion; the extrinsics in the bag are damaged")
        x, y, z, w = x / n, y / n, z / n, w / n
        R = np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
        tr = transform.translation
        return cls.from_arrays(R, np.array([tr.x, tr.y, tr.z], float))

    @property
    def rotation(self) -> np.ndarray:
        return np.asarray(self.R, float)

    @property
    def translation(self) -> np.ndarray:
        return np.asarray(self.t, float)

    def then(self, other: Rigid) -> Rigid:
        """Apply ``self`` first, then ``other``."""
        return Rigid.from_arrays(other.rotation @ self.rotation, other.rotation @ self.translation + other.translation)

    def inverse(self) -> Rigid:
        Rt = self.rotation.T
        return Rigid.from_arrays(Rt, -Rt @ self.translation)

    def is_identity(self, tol: float = 1e-9) -> bool:
        return bool(np.allclose(self.rotation, np.eye(3), atol=tol) and np.allclose(self.translation, 0.0, atol=tol))


def align_depth_to_color(depth_m: np.ndarray, depth_cam: PinholeCamera, color_cam: PinholeCamera, depth_to_color: Rigid) -> np.ndarray:
    """Depth (m, depth camera pixels; 0 or NaN = none) -> depth (float32 m) at the colour camera's pixels, NaN = none.

    ``depth_to_color`` maps depth-camera points to colour-camera points (``p_c = R p_d + t``). Each valid
    depth pixel's footprint (its corners at +-0.5 px) is back-projected at its depth, moved to the colour
    camera and projected; it fills the colour pixels whose centres lie inside it (so a lower-resolution
    depth leaves no pinholes), at most ``MAX_SPLAT_PX`` per axis; one holding no centre fills the pixel
    under its centre if no other footprint holds that pixel's centre. Where several fall on one colour
    pixel the nearest wins. The value stored is Z in the colour camera. Pinhole model both sides.
    """
    z_d = np.asarray(depth_m, dtype=np.float64)
    if z_d.shape != (depth_cam.height, depth_cam.width):
        raise BagError(f"depth image is {z_d.shape[1]}x{z_d.shape[0]} but its camera_info says {depth_cam.width}x{depth_cam.height}")
    if depth_cam == color_cam and depth_to_color.is_identity():
        return np.where(np.isfinite(z_d) & (z_d > 0), z_d, np.nan).astype(np.float32)
    v, u = np.nonzero(np.isfinite(z_d) & (z_d > 0))
    z = z_d[v, u]
    R, t = depth_to_color.rotation, depth_to_color.translation
    u = u.astype(np.float64)
    v = v.astype(np.float64)

    def to_color(du: float, dv: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = (u + du - depth_cam.cx) / depth_cam.fx * z
        y = (v + dv - depth_cam.cy) / depth_cam.fy * z
        X = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
        Y = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
        Z = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            return color_cam.fx * X / Z + color_cam.cx, color_cam.fy * Y / Z + color_cam.cy, Z

    xa, ya, _ = to_color(-0.5, -0.5)
    xb, yb, _ = to_color(0.5, 0.5)
    xc, yc, zc = to_color(0.0, 0.0)
    with np.errstate(invalid="ignore"):
        # The colour pixels whose centres lie in the footprint [min, max): neighbouring footprints of one
        # surface tile the image without overlap, so noise is not min-filtered by the z-buffer (librealsense
        # rounds both corners and covers one pixel more per axis, biasing noisy depth towards the camera).
        x0 = np.ceil(np.minimum(xa, xb))
        x1 = np.ceil(np.maximum(xa, xb)) - 1
        y0 = np.ceil(np.minimum(ya, yb))
        y1 = np.ceil(np.maximum(ya, yb)) - 1
        # A footprint smaller than a pixel that holds no centre (depth finer than colour) fills the pixel
        # under its centre, but only where no footprint holding that pixel's centre did: the one that
        # covers the centre is the sample, the others would again be min-filtered.
        primary = (x1 >= x0) & (y1 >= y0)
        x0, x1 = np.where(x1 < x0, np.floor(xc + 0.5), x0), np.where(x1 < x0, np.floor(xc + 0.5), x1)
        y0, y1 = np.where(y1 < y0, np.floor(yc + 0.5), y0), np.where(y1 < y0, np.floor(yc + 0.5), y1)
        keep = (zc > 0) & np.isfinite(x0 + x1 + y0 + y1)
        keep &= (x1 >= 0) & (x0 <= color_cam.width - 1) & (y1 >= 0) & (y0 <= color_cam.height - 1)
    x0, x1, y0, y1, zc, primary = (a[keep] for a in (x0, x1, y0, y1, zc, primary))
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    nx = np.minimum(x1.astype(np.int64) - x0 + 1, MAX_SPLAT_PX)
    ny = np.minimum(y1.astype(np.int64) - y0 + 1, MAX_SPLAT_PX)
    n_px = color_cam.width * color_cam.height
    # float32 buffers: rounding to float32 keeps order, so the nearest is the same as in float64
    zc32 = zc.astype(np.float32)
    zbuf = np.full(n_px, np.inf, np.float32)
    fallback = np.full(n_px, np.inf, np.float32)
    # A loop over the footprint's offsets (at most MAX_SPLAT_PX**2, usually 1-4), each over only the
    # footprints that reach it (most are 1-2 px a side, a few up to 8).
    for dy in range(int(ny.max(initial=0))):
        rows = np.flatnonzero(ny > dy)
        for dx in range(int(nx[rows].max(initial=0))):
            k = rows[nx[rows] > dx]
            xs, ys = x0[k] + dx, y0[k] + dy
            m = (xs >= 0) & (xs < color_cam.width) & (ys >= 0) & (ys < color_cam.height)
            k, spot = k[m], ys[m] * color_cam.width + xs[m]
            first = primary[k]
            np.minimum.at(zbuf, spot[first], zc32[k[first]])
            np.minimum.at(fallback, spot[~first], zc32[k[~first]])
    np.copyto(zbuf, fallback, where=np.isinf(zbuf))
    zbuf[np.isinf(zbuf)] = np.nan
    return zbuf.reshape(color_cam.height, color_cam.width)


def pair_by_time(color_ns: np.ndarray, depth_ns: np.ndarray, max_skew_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices (colour, depth) of each colour message and the depth message nearest in time within the skew."""
    c = np.asarray(color_ns, dtype=np.int64)
    d = np.asarray(depth_ns, dtype=np.int64)
    if c.size == 0 or d.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    j = np.clip(np.searchsorted(d, c), 1, d.size - 1) if d.size > 1 else np.zeros(c.size, np.int64)
    if d.size > 1:
        j = np.where(np.abs(d[j - 1] - c) <= np.abs(d[j] - c), j - 1, j)
    ok = np.abs(d[j] - c) <= max_skew_ns
    return np.flatnonzero(ok), j[ok]
