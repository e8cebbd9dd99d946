"""Height of a clicked point above a plane: the floor or a table, clicked as a region or found under the point.

Steps (metres, px): the point is where the click's viewing ray meets the robust plane of the window
around it (``measure.planes.fit_plane``, Eq. 9-10), or, with no base clicked, of the surface grown from
it where that is the window's own plane (``measure.planes.joined_another``); the base is the robust
plane of a clicked polygon or grown from one click, or the plane the clicked surface stands on: the
dense level parallel to it below it (``measure.support.parallel_support``), else the dominant plane
around it (``support_plane``); the height is the signed distance n . P + o of the point from the base
(Eq. 12). Its one-sigma adds in quadrature the two planes' covariances (propagated with their sigma
points), the click's ``click_px`` along x and y and a disparity offset common to the frame
(``measure.planes.CALIBRATION_PX``), times ``HEIGHT_SIGMA_SCALE`` (docs/decisions/shape-uncertainty.md).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from measure.planes import SEED_HALF_PX, GrownPlane, Plane, fit_plane, grow_plane, joined_another, offset_plane, sigma_of, window_pixels
from measure.sampling import check_point
from measure.shape_types import ShapeMeasurement
from measure.support import check_options, check_points, parallel_support, shrunk_pixels, support_plane, verdict
from measure.types import Frame, MeasureError, MeasureOptions

HEIGHT_SIGMA_SCALE = 1.0
MIN_DROP_M = 0.02  # a level this close below the top is the top's own noise, not a base
EDGE_SHARE = 0.6  # a click window with fewer of its pixels on its plane straddles an edge
INNER_PX = 8  # the grown surface's plane refit this far inside its outline (a box_edges.FATTEN_REACH_PX)
MIN_INNER_PX = 60
FEW_LEVELS = 3  # a click window on this many disparity levels or fewer: its plane is the rounding's


def window_plane(frame: Frame, x: float, y: float, seed: int) -> Plane:
    """The robust plane of the (2 SEED_HALF_PX + 1)² window around pixel (x, y)."""
    try:
        return fit_plane(frame, *window_pixels(frame, x, y), seed)
    except MeasureError as err:
        raise MeasureError(f"the click ({x:g}, {y:g}) is not on a surface with depth: {err}") from None


def _levels(frame: Frame, x: float, y: float) -> int:
    """Distinct valid disparities in the click window around pixel (x, y)."""
    d = frame.disparity[window_pixels(frame, x, y)[::-1]]
    return int(np.unique(d[frame.valid(d)]).size)


def inner_plane(frame: Frame, grown: GrownPlane, seed: int) -> Plane:
    """The grown surface's plane refit on its pixels at least ``INNER_PX`` inside its outline: next to
    a crease the grown surface holds side-face pixels within its tolerance (two levels on integer
    disparity), which tilt its plane. With fewer than ``MIN_INNER_PX`` such pixels the grown plane stays."""
    import cv2

    inner = cv2.erode(grown.mask.astype(np.uint8), np.ones((2 * INNER_PX + 1,) * 2, np.uint8))
    ys, xs = np.nonzero(inner)
    if len(xs) < MIN_INNER_PX:
        return grown.plane
    try:
        return fit_plane(frame, xs, ys, seed, start=grown.plane)
    except MeasureError:
        return grown.plane


def region_plane(frame: Frame, vertices: np.ndarray, seed: int, erode_px: int = 0) -> Plane:
    """The robust plane of the pixels inside a clicked polygon (shrunk by ``erode_px`` when that leaves enough)."""
    xs, ys = shrunk_pixels(frame.shape, vertices, erode_px)
    if erode_px and len(xs) < 100:
        xs, ys = shrunk_pixels(frame.shape, vertices, 0)
    return fit_plane(frame, xs, ys, seed)


def height_above(top: Plane, base: Plane, x: float, y: float, click_px: float) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Eq. 12: height (m) of pixel (x, y) on ``top`` above ``base``, its model one-sigma, the point and its foot."""
    n, o = base.metric()
    p = top.points_at(x, y)
    h = float(n @ p + o)
    n_off, o_off = offset_plane(base).metric()
    s_offset = abs(float(n_off @ offset_plane(top).points_at(x, y) + o_off) - h)
    tops = top.points_at(x, y, top.coefficient_samples())
    s_top = float(sigma_of(tops @ n + o))
    s_base = float(sigma_of(np.array([(lambda m: m[0] @ p + m[1])(base.metric(c)) for c in base.coefficient_samples()])))
    c = click_px
    moved = top.points_at(np.array([x + c, x - c, x, x]), np.array([y, y, y + c, y - c])) @ n + o
    s_click = math.hypot((moved[0] - moved[1]) / 2, (moved[2] - moved[3]) / 2)
    return h, math.sqrt(s_top**2 + s_base**2 + s_click**2 + s_offset**2), p, p - h * n


def measure_height(frame: Frame, point: tuple[float, float], base: Sequence[tuple[float, float]] | None = None,
                   options: MeasureOptions | None = None) -> ShapeMeasurement:
    """Height (m) of the clicked ``point`` (x, y px) above a plane; the module docstring has the steps.

    Args:
        frame: the frame; ``point`` a click on the object (its top, or any point of it).
        base: the floor or table to measure from: one click (x, y px) on it (its plane grown from
            there), or three or more around a region of it; None: the plane the clicked surface stands on.
        options: ``click_px`` and ``seed`` are used.

    Returns:
        A :class:`ShapeMeasurement` of kind "height" whose ``points_m`` are the point and its foot.

    Raises:
        MeasureError: a click outside the image or on no surface with depth, a base of two clicks, or no
            plane found under the point.
    """
    t0 = time.perf_counter()
    opts = check_options(options)
    x, y = check_point(frame, point, "point")
    top = window_plane(frame, x, y, opts.seed)
    reasons: list[str] = []
    if top.n_support < EDGE_SHARE * top.n_points:
        reasons.append("point on a depth edge")
    if base is not None:
        verts = check_points(frame, base, 1, "a base")
        if len(verts) == 1:  # one click on the base: the plane grown from it over its surface
            floor = grow_plane(frame, tuple(verts[0]), opts.seed).plane
        elif len(verts) == 2:
            raise MeasureError("a base is one click on the floor or table, or at least 3 clicks around a region of it; "
                               "got 2: add a click")
        else:
            floor = region_plane(frame, verts, opts.seed, erode_px=3)
        clicks = ((x, y), *(tuple(v) for v in verts))
    else:
        grown = grow_plane(frame, (x, y), opts.seed, window=top)
        # A level top (a box, a table) stands on a parallel level: the ring's dense level below it is the
        # floor or table alone, where a plane fit on the whole ring can tilt across side faces and a
        # second level (a box on a table). Other tops take the ring's dominant plane.
        floor = parallel_support(frame, grown.mask, grown.plane, seed=opts.seed, min_drop_m=MIN_DROP_M)
        if floor is None:
            floor = support_plane(frame, grown.mask, top.points_at(x, y), seed=opts.seed)
        if floor is None:
            raise MeasureError("no plane found under the point; click three or more points around a region of "
                               "the floor or table to measure from")
        clicks = ((x, y),)
        # A window on a few quantized levels puts the point up to half a level off; a plane over the
        # whole surface grown from it (where that is the window's own) averages many levels.
        if _levels(frame, x, y) <= FEW_LEVELS and not joined_another(top, grown.plane, x, y):
            top = inner_plane(frame, grown, opts.seed)
    h, sigma, p, foot = height_above(top, floor, x, y, opts.click_px)
    if h <= 0:
        raise MeasureError("the point is not above the base plane (it is on it or behind it); click the object's top "
                           "and a base region under it")
    sigma *= HEIGHT_SIGMA_SCALE
    quality, why, interval = verdict(h, sigma, reasons, unreliable=False)
    return ShapeMeasurement("height", h, "m", sigma, interval, quality, why, clicks,
                            (tuple(map(float, p)), tuple(map(float, foot))),
                            elapsed_ms=(time.perf_counter() - t0) * 1000.0)
