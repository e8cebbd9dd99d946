"""The one Arrow schema of a batch's result rows: every row, error rows included, has every column.

Built from the task table's columns, the :class:`measure.MeasureOptions` fields and the
:class:`measure.Measurement` fields, so a group that starts with an error row encodes its valid rows
with the same columns as any other group (inferring the columns from the first row lost them).
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
TASK_TYPES: dict[str, str] = {
    "task": "int64",
    "task_key": "string",
    "source": "string",
    "frame": "int64",
    "p1_x": "float64",
    "p1_y": "float64",
    "p2_x": "float64",
    "p2_y": "float64",
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


def extra_column(name: str) -> str:
    """The result column of a task table's own column (``task_`` in front where a result column has its name)."""
    taken = {**TASK_TYPES, **RUN_TYPES, **option_types(), **{measurement_column(k): v for k, v in MEASUREMENT_TYPES.items()}}
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
    fields += [pa.field(measurement_column(k), _arrow(v)) for k, v in MEASUREMENT_TYPES.items()]
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
