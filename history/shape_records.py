"""A shape measurement's row in the history database and the record the API answers for it.

A shape ("box", "height", "path", "area": :class:`measure.ShapeMeasurement`,
:class:`measure.BoxMeasurement`) lives in the ``measurements`` table beside the segments, its ``kind``
column naming it. The segment columns hold what they can: ``p1`` the first click and ``p2`` the last
(px), ``method`` the options' method, ``fit`` the kind, no samples, and NULL for the segment's
lengths. ``extra`` holds ``shape``: the clicks (``points``), the base plane's clicks (``on``, a
height's; else None), the core's ``result`` (its ``to_dict``, unabridged) and ``draw_px`` (what to
draw on the frame, px), beside the name, the note and the request's context as for a segment.

:func:`shape_record` gives the record: the stored fields and the values read off the result —
``value``, ``unit``, ``uncertainty`` (1σ) and ``interval`` (95 %) of a height, a path or an area
(m, or m² for an area), ``dimensions_m`` (length >= width, height), ``dimension_sigmas_m`` and
``dimension_intervals_m`` of a box (whose ``value`` is None).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

from history.schema import MEASUREMENT_INSERT
from measure import SHAPE_KINDS

Points = Sequence[Sequence[float | None]]


def _xy(points: Points | None) -> list[list[float | None]] | None:
    """``points`` as JSON-ready pairs (None stays None: a corner the core could not place)."""
    return None if points is None else [[None if v is None else float(v) for v in p[:2]] for p in points]


def shape_row_values(
    created: float, frame_id: int, frame_uid: str, source: str, kind: str, points: Points, on: Points | None,
    options: dict[str, Any], result: dict[str, Any], draw_px: Points, context: dict[str, Any] | None,
) -> tuple[Any, ...]:  # fmt: skip
    """The values of :data:`history.schema.MEASUREMENT_INSERT` for one shape measurement of ``kind``
    (one of ``measure.SHAPE_KINDS``; a ValueError otherwise): ``points`` and ``on`` as clicked (px),
    ``result`` the core's ``to_dict()``, ``draw_px`` what to draw (px)."""
    if kind not in SHAPE_KINDS:
        raise ValueError(f"kind must be one of {', '.join(SHAPE_KINDS)} (got {kind!r})")
    clicks = _xy(points) or []
    shape = {"points": clicks, "on": _xy(on), "result": result, "draw_px": _xy(draw_px)}
    columns = {
        "created": created, "frame_id": frame_id, "frame_uid": frame_uid, "source": source,
        "p1_x": clicks[0][0], "p1_y": clicks[0][1], "p2_x": clicks[-1][0], "p2_y": clicks[-1][1],
        "options": json.dumps(options), "distance_m": None, "method": str(options.get("method", "")), "fit": kind,
        "p1_m": "[]", "p2_m": "[]", "basic_distance_m": None, "uncertainty_m": None,
        "n_samples": 0, "n_valid": 0, "n_support": 0, "samples_px": "[]", "support": "[]", "gap_detected": 0,
        "warnings": "[]", "elapsed_ms": float(result.get("elapsed_ms", 0.0)), "thumb": None,
        "extra": json.dumps({"shape": shape} | (context or {})), "kind": kind,
    }  # fmt: skip
    return tuple(columns[name] for name in MEASUREMENT_INSERT)


def shape_values(kind: str, result: Mapping[str, Any]) -> dict[str, Any]:
    """The answer read off a shape's ``result``: value, unit, 1σ and 95 % interval (a box: None, and
    its three dimensions with their 1σ and intervals instead), quality and reasons."""
    common = {"quality": result.get("quality"), "reasons": list(result.get("reasons", []))}
    if kind == "box":
        dims = [result.get("length_m"), result.get("width_m"), result.get("height_m")]
        return common | {
            "value": None, "unit": "m", "uncertainty": None, "interval": None, "dimensions_m": dims,
            "dimension_sigmas_m": list(result.get("uncertainty_m", [])), "dimension_intervals_m": list(result.get("intervals_m", [])),
        }  # fmt: skip
    return common | {
        "value": result.get("value"), "unit": result.get("unit"), "uncertainty": result.get("uncertainty"),
        "interval": result.get("interval"), "dimensions_m": None, "dimension_sigmas_m": None, "dimension_intervals_m": None,
    }  # fmt: skip


def head(row: Mapping[str, Any], extra: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The fields every record starts with, a segment's or a shape's: name, note, id, kind, time
    (``created``, s since the epoch), the frame and the source."""
    return {
        "name": str(extra.get("name", "")),
        "note": str(extra.get("note", "")),
        "id": row["id"],
        "kind": kind,
        "created": row["created"],
        "frame_id": row["frame_id"],
        "frame_uid": row["frame_uid"],
        "source": row["source"],
    }


def shape_record(row: Mapping[str, Any]) -> dict[str, Any]:
    """The record of a shape row (an ``sqlite3.Row`` or a mapping with the same keys)."""
    extra = json.loads(row["extra"] or "{}")
    shape = extra.pop("shape", {})
    result = shape.get("result", {})
    kind = str(row["kind"])
    return {
        **extra,  # the request's context (source_kind, frame_index, ...); never shadows ours
        **head(row, extra, kind),
        "created_at": row["created"],
        "options": json.loads(row["options"]),
        "points": shape.get("points", []),
        "on": shape.get("on"),
        **shape_values(kind, result),
        "draw_px": shape.get("draw_px", []),
        "result": result,
        "elapsed_ms": row["elapsed_ms"],
        "pinned": bool(row["pinned"]),
    }
