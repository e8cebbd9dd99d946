"""Area of a polygon clicked on one planar surface (m²).

Steps: the robust plane of the pixels inside the polygon, shrunk by ``ERODE_PX`` away from its
edges (``measure.height.region_plane``, Eq. 9-10); each corner where its click's viewing ray meets
that plane; the area of the 3D polygon, A = |sum_i (P_i x P_i+1) . n| / 2 (Eq. 13). One-sigma: the
plane's covariance through its sigma points, each corner moved ``click_px`` along x and y and a
disparity offset common to the frame (``measure.planes.CALIBRATION_PX``), in quadrature, times
``AREA_SIGMA_SCALE``. The answer is "unreliable" when fewer than ``ONE_PLANE_SHARE``
of the polygon's pixels lie on the plane within the sensor's noise (``one_plane_share``): the polygon
does not lie on one surface.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from measure.height import region_plane
from measure.planes import INLIER_SIGMAS, MIN_SIGMA_PX, Plane, offset_plane, sigma_of
from measure.shape_types import ShapeMeasurement
from measure.support import check_options, check_points, cross2, polygon_mask, verdict
from measure.types import Frame, MeasureError, MeasureOptions

AREA_SIGMA_SCALE = 1.0
ERODE_PX = 4
ONE_PLANE_SHARE = 0.7


def _crosses(v: np.ndarray) -> bool:
    """Whether two non-adjacent edges of the closed polygon ``v`` (n x 2) cross."""
    n = len(v)
    a, b = v, np.roll(v, -1, axis=0)

    def orient(p, q, r):
        return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

    i, j = np.triu_indices(n, 2)
    keep = (j - i) % n != n - 1 if n > 3 else np.zeros(len(i), bool)
    i, j = i[keep], j[keep]
    o1, o2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
    o3, o4 = orient(a[j], b[j], a[i]), orient(a[j], b[j], b[i])
    return bool(((o1 * o2 < 0) & (o3 * o4 < 0)).any())


def one_plane_share(frame: Frame, plane: Plane, vertices: np.ndarray) -> float:
    """Share of the pixels with depth inside the polygon ``vertices`` within ``INLIER_SIGMAS`` noise scales of ``plane``.

    The noise scale comes from differences of horizontally neighbouring pixels (1.4826 MAD / sqrt(2),
    floored at 0.75 of the disparity quantum), not from the plane's own residuals: a plane fit across two
    surfaces inflates its residual scale until most pixels look like inliers; neighbour differences
    cancel the surfaces and keep the sensor's noise."""
    mask, x0, y0 = polygon_mask(frame.shape, vertices)
    d = frame.disparity[y0:y0 + mask.shape[0], x0:x0 + mask.shape[1]]
    pair = mask[:, 1:] & mask[:, :-1]
    diff = (d[:, 1:] - d[:, :-1])[pair]
    diff = diff[np.isfinite(diff)]
    noise = 1.4826 * float(np.median(np.abs(diff))) / math.sqrt(2.0) if diff.size else 0.0
    noise = max(noise, 0.75 * plane.quantum, MIN_SIGMA_PX)
    ys, xs = np.nonzero(mask)
    r = d[ys, xs] - plane.disparity_at(xs + x0, ys + y0)
    r = r[np.isfinite(r)]
    return float(np.mean(np.abs(r) <= INLIER_SIGMAS * noise)) if r.size else 0.0


def polygon_area(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Eq. 13: area (m²) of closed 3D polygons ``points`` (..., n, 3) on a plane of unit ``normal``."""
    cross = np.cross(points, np.roll(points, -1, axis=-2)).sum(axis=-2)
    return np.abs(cross @ normal) / 2.0


def area_on(plane: Plane, verts: np.ndarray, click_px: float) -> tuple[float, float, np.ndarray]:
    """Area (m²) of the polygon ``verts`` (n x 2 px) on ``plane``, its model one-sigma and its 3D corners."""
    n = plane.metric()[0]
    corners = plane.points_at(verts[:, 0], verts[:, 1])
    area = float(polygon_area(corners, n))
    samples = np.array([polygon_area(plane.points_at(verts[:, 0], verts[:, 1], c), plane.metric(c)[0])
                        for c in plane.coefficient_samples()])
    k = len(verts)
    shifts = np.zeros((4 * k, k, 2))
    for i in range(k):  # corner i moved by +-click_px along x, then along y
        shifts[4 * i, i, 0], shifts[4 * i + 1, i, 0] = click_px, -click_px
        shifts[4 * i + 2, i, 1], shifts[4 * i + 3, i, 1] = click_px, -click_px
    moved = verts[None] + shifts
    am = polygon_area(plane.points_at(moved[..., 0], moved[..., 1]), n).reshape(k, 2, 2)
    s_click = math.sqrt(float((((am[:, :, 0] - am[:, :, 1]) / 2) ** 2).sum()))
    moved_plane = offset_plane(plane)
    s_offset = abs(float(polygon_area(moved_plane.points_at(verts[:, 0], verts[:, 1]), moved_plane.metric()[0])) - area)
    return area, math.sqrt(float(sigma_of(samples)) ** 2 + s_click**2 + s_offset**2), corners


def measure_area(frame: Frame, vertices: Sequence[tuple[float, float]], options: MeasureOptions | None = None) -> ShapeMeasurement:
    """Area (m²) of the polygon of clicked ``vertices`` (x, y px, in order around it) on one planar surface.

    Raises:
        MeasureError: fewer than three clicks, clicks outside the image, edges that cross, or no
            surface with depth inside the polygon.
    """
    t0 = time.perf_counter()
    opts = check_options(options)
    verts = check_points(frame, vertices, 3, "an area")
    if _crosses(verts):
        raise MeasureError("the polygon's edges cross; click its corners in order around it")
    if abs(float(cross2(verts - verts[0], np.roll(verts, -1, axis=0) - verts[0]).sum())) < 2 * 9.0:
        raise MeasureError("the polygon encloses almost no pixels; click corners farther apart")
    plane = region_plane(frame, verts, opts.seed, erode_px=ERODE_PX)
    area, sigma, corners = area_on(plane, verts, opts.click_px)
    sigma *= AREA_SIGMA_SCALE
    reasons: list[str] = []
    share = one_plane_share(frame, plane, verts)
    off_plane = share < ONE_PLANE_SHARE
    if off_plane:
        reasons.append(f"polygon does not lie on one plane ({100 * share:.0f} % of its pixels do)")
    quality, why, interval = verdict(area, sigma, reasons, unreliable=off_plane)
    return ShapeMeasurement("area", area, "m2", sigma, interval, quality, why, tuple(map(tuple, verts)),
                            tuple(tuple(map(float, c)) for c in corners), elapsed_ms=(time.perf_counter() - t0) * 1000.0)
