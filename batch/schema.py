"""The one Arrow schema of a batch's result rows: every row, error rows included, has every column.

Built from the task table's columns, the :class:`measure.MeasureOptions` fields, the
:class:`measure.Measurement` fields (a segment's answer) and the shape answers' fields
(:class:`measure.ShapeMeasurement` of a height, a path or an area; :class:`measure.BoxMeasurement`,
its (length, width, height) tuples split into one column each), so a group that starts with an
error row, or mixes kinds, encodes every row with the same columns as any other group (inferring
the columns from the first row lost them). A row fills the columns of its kind; the others are null.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any

from measure import MeasureOptions

# Every field of Measurement.to_dict() and its Arrow type; a test checks the two name the same fields.
MEASUREMENT_TYPES: dict[str, str] = {
    "distance_m": "float64",
    "method": "string",
    "fit": "string",
    "p1_m": "list<float64>",
    "p2_m": "list<float64>",
    "basic_distance_m": "float64",
    "uncertainty_m": "float64",
    "n_samples": "int64",
    "n_valid": "int64",
    "n_support": "int64",
    "samples_px": "list<list<float64>>",
    "support": "list<bool>",
    "gap_detected": "bool",
    "warnings": "list<string>",
    "elapsed_ms": "float64",
    "interval_m": "list<float64>",
    "quality": "string",
    "reasons": "list<string>",
    "frames_used": "int64",
    "single_frame_uncertainty_m": "float64",
}
# A height's, a path's or an area's ShapeMeasurement.to_dict() fields beyond the shared ones below.
SHAPE_TYPES: dict[str, str] = {
    "value": "float64",
    "unit": "string",
    "uncertainty": "float64",
    "interval": "list<float64>",
    "points_m": "list<list<float64>>",
    "parts": "list<float64>",
    "part_sigmas": "list<float64>",
}
BOX_DIMENSIONS = ("length", "width", "height")
# A box's BoxMeasurement.to_dict() fields: its uncertainty_m and intervals_m, one value per dimension,
# become BOX_SPLIT's columns ("length_sigma_m", "length_interval_m", ...).
BOX_SPLIT: dict[str, tuple[str, str]] = {"uncertainty_m": ("{}_sigma_m", "float64"), "intervals_m": ("{}_interval_m", "list<float64>")}
BOX_TYPES: dict[str, str] = {
    "length_m": "float64",
    "width_m": "float64",
    "height_m": "float64",
    **{pattern.format(d): t for pattern, t in BOX_SPLIT.values() for d in BOX_DIMENSIONS},
    "corners_m": "list<list<float64>>",
    "base_corners_m": "list<list<float64>>",
    "corners_px": "list<list<float64>>",
    "base_corners_px": "list<list<float64>>",
    "support_plane": "list<float64>",
    "n_top_px": "int64",
}
SHAPE_SHARED = ("quality", "reasons", "elapsed_ms")  # a shape's fields that fill the segment's columns of the same name
SHAPE_IN_TASK = ("kind", "clicks_px", "click_px")  # a shape's fields the task's columns already hold (kind, points)
TASK_TYPES: dict[str, str] = {
    "task": "int64",
    "task_key": "string",
    "source": "string",
    "frame": "int64",
    "kind": "string",
    "p1_x": "float64",
    "p1_y": "float64",
    "p2_x": "float64",
    "p2_y": "float64",
    "points": "list<list<float64>>",
    "on": "list<list<float64>>",
}
RUN_TYPES: dict[str, str] = {
    "run": "string",
    "version": "string",
    "worker": "string",
    "finished": "float64",
    "frame_read_ms": "float64",
    "error": "string",
    "error_type": "string",
    "error_field": "string",
}
_OPTION_TYPES = {"bool": "bool", "int": "int64", "float": "float64", "str": "string"}


def _arrow(name: str):
    import pyarrow as pa

    if name.startswith("list<"):
        return pa.list_(_arrow(name[5:-1]))
    return {"float64": pa.float64(), "int64": pa.int64(), "string": pa.string(), "bool": pa.bool_()}[name]


def option_types() -> dict[str, str]:
    """``opt_<field>`` -> Arrow type name of every MeasureOptions field."""
    out = {}
    for f in dataclasses.fields(MeasureOptions):
        kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "str")
        out[f"opt_{f.name}"] = _OPTION_TYPES.get(kind, "string")
    return out


def measurement_column(name: str) -> str:
    """The result column of a Measurement field (``m_`` in front where a task or run column has its name)."""
    return f"m_{name}" if name in TASK_TYPES or name in RUN_TYPES else name


def answer_types() -> dict[str, str]:
    """Every answer column (a segment's, then a shape's, then a box's) -> its Arrow type name."""
    return {**{measurement_column(k): v for k, v in MEASUREMENT_TYPES.items()}, **SHAPE_TYPES, **BOX_TYPES}


def shape_columns(result: Any) -> dict[str, Any]:
    """The answer columns of a shape's result (a ShapeMeasurement or BoxMeasurement): its ``to_dict()``
    fields by :data:`SHAPE_TYPES`, :data:`BOX_TYPES` and :data:`SHAPE_SHARED`; NaN as None."""
    out: dict[str, Any] = {}
    for k, v in result.to_dict().items():
        if k in BOX_SPLIT:
            out.update({BOX_SPLIT[k][0].format(d): x for d, x in zip(BOX_DIMENSIONS, v)})
        elif k not in SHAPE_IN_TASK:
            out[measurement_column(k) if k in SHAPE_SHARED else k] = v
    return out


def extra_column(name: str) -> str:
    """The result column of a task table's own column (``task_`` in front where a result column has its name)."""
    taken = {**TASK_TYPES, **RUN_TYPES, **option_types(), **answer_types()}
    return f"task_{name}" if name in taken else name


def _extra_type(values: Iterable[Any]):
    """The Arrow type of a carried-through column: inferred over all its values, a string column when
    they do not share one (a column holding 3 and "3" is kept as text, never dropped)."""
    import pyarrow as pa

    vals = [None if isinstance(v, float) and math.isnan(v) else v for v in values]
    try:
        t = pa.array(vals).type
    except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError, OverflowError):
        return pa.string()
    return pa.string() if pa.types.is_null(t) else t


def result_schema(extras: Mapping[str, Iterable[Any]] | None = None):
    """The pyarrow schema of every result row of a run whose tasks carry ``extras`` (column -> values)."""
    import pyarrow as pa

    fields = [pa.field(k, _arrow(v)) for k, v in TASK_TYPES.items()]
    for name, values in (extras or {}).items():
        fields.append(pa.field(extra_column(name), _extra_type(values)))
    fields += [pa.field(k, _arrow(v)) for k, v in option_types().items()]
    fields += [pa.field(k, _arrow(v)) for k, v in answer_types().items()]
    fields += [pa.field(k, _arrow(v)) for k, v in RUN_TYPES.items()]
    return pa.schema(fields)


def encode_rows(rows: list[dict[str, Any]], schema) -> bytes:
    """``rows`` as one Parquet file in ``schema``; a value that does not fit its column's type is kept as text."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq

    unknown = {k for r in rows for k in r} - set(schema.names)
    if unknown:  # from_pylist would drop them without a word
        raise ValueError(f"result rows hold columns outside the result schema: {sorted(unknown)}")
    try:
        table = pa.Table.from_pylist(rows, schema=schema)
    except (pa.ArrowInvalid, pa.ArrowTypeError, OverflowError):
        table = pa.Table.from_pylist([_fit(r, schema) for r in rows], schema=schema)
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def _fit(row: dict[str, Any], schema) -> dict[str, Any]:
    import pyarrow as pa

    out = {}
    for k, v in row.items():
        t = schema.field(k).type
        try:
            pa.array([v], type=t)
            out[k] = v
        except (pa.ArrowInvalid, pa.ArrowTypeError, TypeError, ValueError, OverflowError):
            out[k] = str(v) if pa.types.is_string(t) else None
    return out
