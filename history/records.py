"""A measurement's row in the history database and the record (a JSON-ready dict) the API answers.

:func:`row_values` turns a request and its result (``Measurement.to_dict()``, metres) into the
values of :data:`history.schema.MEASUREMENT_INSERT`; :func:`record` turns a row (or the same
values with their id, :func:`record_of_values`) into the record: points in px, lengths in
metres (None where not finite), the result's newer fields, ``name``, ``note``, ``pinned`` and
``kind``. Shape rows (``kind`` other than "segment") are :mod:`history.shape_records`' own.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from history.schema import MEASUREMENT_INSERT, MEASUREMENTS_COLUMNS, SEGMENT
from history.shape_records import head, shape_record

FIXED_RESULT_KEYS = frozenset(
    ("distance_m", "method", "fit", "p1_m", "p2_m", "basic_distance_m", "uncertainty_m", "n_samples", "n_valid",
     "n_support", "samples_px", "support", "gap_detected", "warnings", "elapsed_ms")
)  # fmt: skip


def _num(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def row_values(
    created: float, frame_id: int, frame_uid: str, source: str, p1: tuple[float, float], p2: tuple[float, float],
    options: dict[str, Any], result: dict[str, Any], thumb: bytes | None, context: dict[str, Any] | None,
) -> tuple[Any, ...]:  # fmt: skip
    """The values of :data:`history.schema.MEASUREMENT_INSERT` for one measurement; result keys beyond
    the fixed columns, and ``context``, go to ``extra``."""
    extra = {k: v for k, v in result.items() if k not in FIXED_RESULT_KEYS} | (context or {})
    return (
        created, frame_id, frame_uid, source, float(p1[0]), float(p1[1]), float(p2[0]), float(p2[1]),
        json.dumps(options), result["distance_m"], result["method"], result["fit"], json.dumps(result["p1_m"]),
        json.dumps(result["p2_m"]), result["basic_distance_m"], result["uncertainty_m"], result["n_samples"],
        result["n_valid"], result["n_support"], json.dumps(result["samples_px"]), json.dumps(result["support"]),
        int(result["gap_detected"]), json.dumps(result["warnings"]), result["elapsed_ms"], thumb, json.dumps(extra), SEGMENT,
    )  # fmt: skip


def record_of_values(mid: int, values: tuple[Any, ...]) -> dict[str, Any]:
    """The record of a measurement just inserted with ``values`` as id ``mid`` (not pinned), built
    without reading the database back."""
    stored = {name: _as_stored(name, v) for name, v in zip(MEASUREMENT_INSERT, values)}
    return record({"id": mid, **stored, "pinned": 0})


_REAL = frozenset(name for name, decl in MEASUREMENTS_COLUMNS if decl.startswith("REAL"))
_INTEGER = frozenset(name for name, decl in MEASUREMENTS_COLUMNS if decl.startswith("INTEGER"))


def _as_stored(name: str, value: Any) -> Any:
    """``value`` as SQLite gives it back from column ``name`` (its type affinity: 5 in a REAL
    column reads as 5.0, 3.0 in an INTEGER column as 3)."""
    if value is None or isinstance(value, (str, bytes)):
        return value
    if name in _REAL:
        return float(value)
    if name in _INTEGER and float(value).is_integer():
        return int(value)
    return value


def kind_of(row: Mapping[str, Any]) -> str:
    """What a row measured: its ``kind``, "segment" for a row of a database not migrated yet."""
    return str(row["kind"]) if "kind" in row.keys() else SEGMENT


def record(row: Mapping[str, Any]) -> dict[str, Any]:
    """The record of a row (an ``sqlite3.Row`` or a mapping with the same keys): a segment's with the
    per-sample arrays only when the row has them, a shape's as :func:`history.shape_records.shape_record`."""
    if kind_of(row) != SEGMENT:
        return shape_record(row)
    keys = row.keys()
    extra = json.loads(row["extra"] or "{}")
    return {
        **extra,  # newer Measurement fields (quality, reasons, ...) and frame_index; never shadow ours
        **head(row, extra, SEGMENT),
        "p1": [row["p1_x"], row["p1_y"]],
        "p2": [row["p2_x"], row["p2_y"]],
        "options": json.loads(row["options"]),
        "distance_m": _num(row["distance_m"]),
        "method": row["method"],
        "fit": row["fit"],
        "p1_m": json.loads(row["p1_m"]),
        "p2_m": json.loads(row["p2_m"]),
        "basic_distance_m": _num(row["basic_distance_m"]),
        "uncertainty_m": _num(row["uncertainty_m"]),
        "n_samples": row["n_samples"],
        "n_valid": row["n_valid"],
        "n_support": row["n_support"],
        **({"samples_px": json.loads(row["samples_px"]), "support": json.loads(row["support"])} if "support" in keys else {}),
        "gap_detected": bool(row["gap_detected"]),
        "warnings": json.loads(row["warnings"]),
        "elapsed_ms": row["elapsed_ms"],
        "pinned": bool(row["pinned"]),
    }
