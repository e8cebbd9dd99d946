"""What the page and the thumbnail draw of a shape's answer (a box, a height, a path, an area; measured
by ``measure.measure_shape``), in pixels of the frame.

:func:`draw_px` gives the points to draw: a path's vertices and an area's corners as clicked, a
height's top point and its foot on the base plane projected with the frame's pinhole camera (u = fx X / Z + cx, v = fy Y / Z + cy), a
box's four top corners then its four base corners (``measure.shape_types.outlines`` turns them into
polylines).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from measure import BoxMeasurement, PinholeCamera, ShapeMeasurement


def _px(p: Sequence[float]) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in p]


def _project(camera: PinholeCamera, p: Sequence[float]) -> list[float | None]:
    x, y, z = (float(v) for v in p)
    if not (math.isfinite(z) and z > 0):
        return [None, None]
    return _px((camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy))


def draw_px(result: ShapeMeasurement | BoxMeasurement, camera: PinholeCamera) -> list[list[float | None]]:
    """What to draw of ``result`` on its frame (px; None for a coordinate that is not finite): see
    the module docstring."""
    if isinstance(result, BoxMeasurement):
        return [_px(p) for p in (*result.corners_px, *result.base_corners_px)]
    if result.kind == "height":
        return [_project(camera, p) for p in result.points_m]
    return [_px(p) for p in result.clicks_px]
