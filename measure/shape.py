"""One call for every shape kind: :func:`measure_shape` picks the core's measurement of a box, a height,
a path or an area from the kind's name and its clicks, as the service, the command line and the batch
receive them (a kind and a list of clicks, not a function to call)."""

from __future__ import annotations

from collections.abc import Sequence

from measure.area import measure_area
from measure.box import measure_box
from measure.errors import MeasureError
from measure.height import measure_height
from measure.path import measure_path
from measure.shape_types import SHAPE_KINDS, BoxMeasurement, ShapeMeasurement
from measure.types import Frame, MeasureOptions

ONE_CLICK = ("box", "height")  # kinds measured from one click; the others take the clicks in order


def measure_shape(
    frame: Frame,
    kind: str,
    points: Sequence[Sequence[float]],
    on: Sequence[Sequence[float]] | None = None,
    options: MeasureOptions | None = None,
) -> ShapeMeasurement | BoxMeasurement:
    """The core's answer for a shape of ``kind`` clicked at ``points`` (x, y px) on ``frame``.

    Args:
        frame: the frame.
        kind: one of :data:`measure.SHAPE_KINDS` ("height", "path", "area", "box").
        points: a box's or a height's one click (on the top face, on the object); a path's two or
            more, an area's three or more clicks in order.
        on: a height's base plane: one click on it or three or more around a region of it (None:
            the plane the object stands on); None for the other kinds.
        options: the measurement options (None: the defaults).

    Returns:
        :func:`measure.measure_box`'s :class:`BoxMeasurement` for a box, else the
        :class:`ShapeMeasurement` of :func:`measure.measure_height`, ``measure_path`` or ``measure_area``.

    Raises:
        MeasureError: an unknown kind, a click count the kind does not take, ``on`` for a kind
            other than a height, or what the kind's own measurement refuses.

    Example:
        >>> from measure import measure_shape
        >>> measure_shape(None, "cube", [(1, 2)])
        Traceback (most recent call last):
        ...
        measure.errors.MeasureError: kind 'cube' is not a shape; use one of height, path, area, box
    """
    if kind not in SHAPE_KINDS:
        raise MeasureError(f"kind {kind!r} is not a shape; use one of {', '.join(SHAPE_KINDS)}")
    if on is not None and kind != "height":
        raise MeasureError(f"'on' names the base plane of a height only; leave it out for a {kind}")
    clicks = [tuple(p) for p in points]
    if kind in ONE_CLICK and len(clicks) != 1:
        raise MeasureError(f"a {kind} takes exactly 1 click, got {len(clicks)}; give one point")
    if kind == "box":
        return measure_box(frame, clicks[0], options)  # type: ignore[arg-type]
    if kind == "height":
        return measure_height(frame, clicks[0], [tuple(p) for p in on] if on else None, options)  # type: ignore[arg-type, misc]
    return (measure_path if kind == "path" else measure_area)(frame, clicks, options)  # type: ignore[arg-type]
