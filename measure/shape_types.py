"""Results of the shape measurements: height, path and area (:class:`ShapeMeasurement`) and box
dimensions (:class:`BoxMeasurement`). Metres (m² for areas), pixels, the camera frame.

Both follow :class:`measure.Measurement`: a value, a calibrated one-sigma, a 95 % interval, a verdict
(``"good"``, ``"check"``, ``"unreliable"``) with its reasons, and what to draw; ``to_dict`` gives
the JSON form (NaN becomes None).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

SHAPE_KINDS: tuple[str, ...] = ("height", "path", "area", "box")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _pts(points: tuple) -> list:
    return [[_num(float(v)) for v in p] for p in points]


@dataclass(frozen=True)
class ShapeMeasurement:
    """One height, path or area.

    Args:
        kind: ``"height"``, ``"path"`` or ``"area"`` (str).
        value: the answer (float; m, or m² for an area).
        unit: ``"m"`` or ``"m2"`` (str).
        uncertainty: one-sigma of ``value`` (float, same unit).
        interval: 95 % interval (low, high) of ``value``.
        quality: ``"good"``, ``"check"`` or ``"unreliable"`` (str).
        reasons: why the verdict is not "good" (tuple of str).
        clicks_px: the clicked pixels (x, y) in order (tuple of pairs, px).
        points_m: 3D points to draw (tuple of (x, y, z), m): the path's vertices, the polygon's
            corners on its plane, or the height's top point and its foot on the base plane.
        parts: the legs' lengths of a path, or () (tuple of float, m).
        part_sigmas: the legs' one-sigmas (tuple of float, m).
        elapsed_ms: time taken (float, ms).
    """

    kind: str
    value: float
    unit: str
    uncertainty: float
    interval: tuple[float, float]
    quality: str
    reasons: tuple[str, ...]
    clicks_px: tuple[tuple[float, float], ...]
    points_m: tuple[tuple[float, float, float], ...]
    parts: tuple[float, ...] = ()
    part_sigmas: tuple[float, ...] = ()
    elapsed_ms: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the same field names."""
        return {
            "kind": self.kind,
            "value": _num(self.value),
            "unit": self.unit,
            "uncertainty": _num(self.uncertainty),
            "interval": [_num(v) for v in self.interval],
            "quality": self.quality,
            "reasons": list(self.reasons),
            "clicks_px": _pts(self.clicks_px),
            "points_m": _pts(self.points_m),
            "parts": [_num(v) for v in self.parts],
            "part_sigmas": [_num(v) for v in self.part_sigmas],
            "elapsed_ms": float(self.elapsed_ms),
        }


@dataclass(frozen=True)
class BoxMeasurement:
    """The three dimensions of a box standing on a plane, from a click on its top face.

    Args:
        length_m: the top face's longer side (float, m); ``length_m >= width_m``.
        width_m: the top face's shorter side (float, m).
        height_m: the top face above the supporting plane (float, m).
        uncertainty_m: one-sigma of (length, width, height) (m).
        intervals_m: 95 % intervals of (length, width, height), each (low, high) (m).
        quality: ``"good"``, ``"check"`` or ``"unreliable"`` (str).
        reasons: why the verdict is not "good" (tuple of str).
        corners_m: the top face's four 3D corners in order around it (4 x (x, y, z), m).
        base_corners_m: the same corners dropped onto the supporting plane (m).
        corners_px: ``corners_m`` in the image (4 x (x, y), px), for drawing.
        base_corners_px: ``base_corners_m`` in the image (px).
        support_plane: the supporting plane as (nx, ny, nz, o), n . P + o = 0, unit n towards the camera.
        click_px: the click (x, y) (px).
        n_top_px: pixels of the top face (int).
        elapsed_ms: time taken (float, ms).
    """

    length_m: float
    width_m: float
    height_m: float
    uncertainty_m: tuple[float, float, float]
    intervals_m: tuple[tuple[float, float], ...]
    quality: str
    reasons: tuple[str, ...]
    corners_m: tuple[tuple[float, float, float], ...]
    base_corners_m: tuple[tuple[float, float, float], ...]
    corners_px: tuple[tuple[float, float], ...]
    base_corners_px: tuple[tuple[float, float], ...]
    support_plane: tuple[float, float, float, float]
    click_px: tuple[float, float]
    n_top_px: int
    elapsed_ms: float = 0.0

    @property
    def dimensions_m(self) -> tuple[float, float, float]:
        """(length, width, height) (m)."""
        return (self.length_m, self.width_m, self.height_m)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with the same field names."""
        return {
            "length_m": _num(self.length_m),
            "width_m": _num(self.width_m),
            "height_m": _num(self.height_m),
            "uncertainty_m": [_num(v) for v in self.uncertainty_m],
            "intervals_m": [[_num(a), _num(b)] for a, b in self.intervals_m],
            "quality": self.quality,
            "reasons": list(self.reasons),
            "corners_m": _pts(self.corners_m),
            "base_corners_m": _pts(self.base_corners_m),
            "corners_px": _pts(self.corners_px),
            "base_corners_px": _pts(self.base_corners_px),
            "support_plane": [_num(v) for v in self.support_plane],
            "click_px": [_num(v) for v in self.click_px],
            "n_top_px": int(self.n_top_px),
            "elapsed_ms": float(self.elapsed_ms),
        }


def outlines(kind: str, points: list[list[float | None]]) -> list[tuple[list[list[float]], bool]]:
    """The polylines (points, closed) that draw a measurement of ``kind`` from its drawing points (px;
    a box's are its ``corners_px`` then its ``base_corners_px``; a height's its top point and its foot;
    a path's vertices; an area's corners; a segment's two ends): a line, a polyline, a polygon, or a
    box's top rectangle, base rectangle and four vertical edges. Points not finite (or None) are left out."""
    finite = [[float(v) for v in p] for p in points if all(v is not None and math.isfinite(v) for v in p)]
    if kind == "box" and len(finite) == 8:
        top, base = finite[:4], finite[4:]
        return [(top, True), (base, True), *(([t, b], False) for t, b in zip(top, base))]
    return [(finite, kind in ("area", "box"))]

