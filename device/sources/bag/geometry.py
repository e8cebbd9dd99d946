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
from device.sources.bag.messages import pixels_to_metres

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


def align_depth_to_color(depth_m: np.ndarray, depth_cam: PinholeCamera, color_cam: PinholeCamera, depth_to_color: Rigid, *,
                         disparity_k: float = 0.0, depth_unit_m: float = 0.0) -> np.ndarray:  # fmt: skip
    """Depth (m, depth camera pixels; 0 or NaN = none) -> depth (float32 m) at the colour camera's pixels, NaN = none.

    ``depth_to_color`` maps depth-camera points to colour-camera points (``p_c = R p_d + t``). Each valid
    depth pixel's footprint (its corners at +-0.5 px) is back-projected at its depth, moved to the colour
    camera and projected; it fills the colour pixels whose centres lie inside it (so a lower-resolution
    depth leaves no pinholes), at most ``MAX_SPLAT_PX`` per axis; one holding no centre fills the pixel
    under its centre if no other footprint holds that pixel's centre. Where several fall on one colour
    pixel the nearest wins. The value stored is Z in the colour camera, or the disparity ``disparity_k / Z``
    (float32, px; ``disparity_k = fx * B``) when ``disparity_k`` > 0. Pinhole model both sides. With
    ``depth_unit_m`` > 0, ``depth_m`` is integer depth units as recorded (uint16), each taken as
    ``float32(d) * float32(depth_unit_m)`` metres, as ``messages.pixels_to_metres`` makes them.
    """
    z_d = np.asarray(depth_m)
    if depth_unit_m > 0 and z_d.dtype != np.uint16:
        raise BagError(f"depth in units ({depth_unit_m} m) must be uint16 as recorded (16UC1/mono16), got {z_d.dtype}; give other depth in metres")
    z_d = np.ascontiguousarray(z_d, dtype=z_d.dtype if z_d.dtype in (np.uint16, np.float32, np.float64) else np.float64)
    if z_d.shape != (depth_cam.height, depth_cam.width):
        raise BagError(f"depth image is {z_d.shape[1]}x{z_d.shape[0]} but its camera_info says {depth_cam.width}x{depth_cam.height}")
    if depth_cam == color_cam and depth_to_color.is_identity():
        z = pixels_to_metres(z_d, depth_unit_m) if depth_unit_m > 0 else np.where(np.isfinite(z_d) & (z_d > 0), z_d, np.nan).astype(np.float32)
        return np.divide(np.float32(disparity_k), z) if disparity_k > 0 else z
    from device.sources.bag.kernels import OFFSETS, ray_terms, splat_nearest  # numba compiles on first use: `import device` stays fast

    offsets = np.array(OFFSETS)[:, None]
    xn = (np.arange(depth_cam.width, dtype=np.float64) + offsets - depth_cam.cx) / depth_cam.fx
    yn = (np.arange(depth_cam.height, dtype=np.float64) + offsets - depth_cam.cy) / depth_cam.fy
    cols, rows = ray_terms(depth_to_color.rotation, xn, yn)
    c = np.array([color_cam.fx, color_cam.fy, color_cam.cx, color_cam.cy], np.float32)
    return splat_nearest(z_d, cols, rows, np.asarray(depth_to_color.translation, np.float32), c, color_cam.width, color_cam.height,
                         MAX_SPLAT_PX, float(disparity_k), float(depth_unit_m))  # fmt: skip


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
