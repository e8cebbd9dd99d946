"""The history exported: CSV (one row per measurement, safe to open in a spreadsheet) and JSON.

Both take the database rows in batches, oldest first (:meth:`history.store.Store.batches`), and
give the file as a sequence of chunks, one per batch, so a response streams it without holding
all records (docs/decisions/streamed-exports.md).

CSV (:func:`csv_chunks`): columns :data:`CSV_COLUMNS`; lengths and 3D coordinates in the chosen
unit (:data:`UNITS`), rounded to what each measurement's uncertainty supports
(:func:`supported_decimals`), pixels to 0.1 px; ``frame_url`` opens the saved colour image;
``source_kind`` and ``recording`` say what the frame was read from ("replay" and the recording's
folder, "bag" or "video" and the file; empty for measurements stored before the service kept them). Text
cells go through :mod:`history.csv_safe`, so a name or note typed as a formula is written as text.
The CSV never writes the per-sample arrays, so its rows are read without them. ``kind`` says what a
row measured; a shape's row (:mod:`history.shape_records`) fills ``uncertainty_1sigma``, the
interval, the verdict, ``method`` and ``fit`` (its kind), ``value`` in ``value_unit`` (the unit, or
its square for an area), a box's ``length``/``width``/``height`` with their 1σ, and its clicks
(``points_px``), and leaves a segment's cells blank; a segment leaves the shape's cells blank.

JSON (:func:`json_chunks`): ``{"measurements": [...]}``, every record with its per-sample arrays
copied as the JSON text the database holds, never decoded and encoded again (a shape has none).
"""

from __future__ import annotations

import io
import json
import math
import time
from collections.abc import Iterable, Iterator, Mapping
from decimal import Decimal
from typing import Any

from history import csv_safe
from history.records import record
from history.schema import SEGMENT

UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "in": 1 / 0.0254}

CSV_COLUMNS = (
    "id", "created_utc", "name", "note", "source", "source_kind", "recording", "frame_id", "frame_index", "units", "distance", "uncertainty_1sigma",
    "interval_low", "interval_high", "quality", "reasons", "method", "fit", "basic_distance",
    "p1_x_px", "p1_y_px", "p2_x_px", "p2_y_px", "p1_X", "p1_Y", "p1_Z", "p2_X", "p2_Y", "p2_Z",
    "n_samples", "n_valid", "n_support", "gap_detected", "warnings", "frame_url",
    "kind", "value", "value_unit", "length", "width", "height", "length_1sigma", "width_1sigma", "height_1sigma", "points_px",
)  # fmt: skip
SHAPE_CELLS = CSV_COLUMNS.index("value")  # where a shape's own cells start; a segment leaves them blank
SEGMENT_ONLY = CSV_COLUMNS.index("frame_url") - CSV_COLUMNS.index("basic_distance")  # cells a shape leaves blank


def supported_decimals(sigma: float | None, factor: float) -> int:
    """Decimals that keep two significant digits of the 1-sigma uncertainty ``sigma`` (m) in a unit of
    ``factor`` per metre: more would be noise, fewer would hide the precision. 4 when unknown."""
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return 4
    return int(min(6, max(0, 1 - math.floor(math.log10(sigma * factor)))))


def _rounded(v: Any, sigma: float | None, factor: float) -> Decimal | str:
    """``v`` (m or m²) times ``factor``, to the decimals ``sigma`` supports; "" for None. A Decimal is a
    number to the CSV writer (csv_safe leaves it, so -0.250 stays a negative length) and keeps the
    rounding's trailing zeros, which a float would drop."""
    return "" if v is None else Decimal(f"{float(v) * factor:.{supported_decimals(sigma, factor)}f}")


def _sigma(v: float | None, factor: float) -> str:
    return "" if v is None else f"{v * factor:.2g}"


def _segment_cells(r: dict[str, Any], k: float) -> list[Any]:
    """The cells from ``distance`` to ``warnings`` of a segment (lengths in a unit of ``k`` per metre)."""
    sigma = r["uncertainty_m"]

    def length(v: Any) -> Decimal | str:
        return _rounded(v, sigma, k)

    lo, hi = (list(r.get("interval_m") or []) + [None, None])[:2]
    return [
        length(r["distance_m"]), _sigma(sigma, k), length(lo), length(hi), r.get("quality", ""), "; ".join(r.get("reasons", [])),
        r["method"], r["fit"], length(r["basic_distance_m"]),
        *(Decimal(f"{v:.1f}") for v in (*r["p1"], *r["p2"])), *(length(v) for v in (*r["p1_m"], *r["p2_m"])),
        r["n_samples"], r["n_valid"], r["n_support"], int(r["gap_detected"]), "; ".join(r["warnings"]),
    ]  # fmt: skip


def _shape_cells(r: dict[str, Any], k: float, units: str) -> tuple[list[Any], list[Any]]:
    """A shape's cells from ``distance`` to ``warnings`` (its 1σ, interval, verdict, method and kind;
    no segment values) and from ``value`` on: the value in ``units`` (``units`` + "2" for an area), a
    box's dimensions with their 1σ, and the clicks (px)."""
    area = r["unit"] == "m2"
    f = k * k if area else k
    lo, hi = (list(r.get("interval") or []) + [None, None])[:2]
    sigma = r["uncertainty"]
    middle = [
        "", _sigma(sigma, f), _rounded(lo, sigma, f), _rounded(hi, sigma, f), r["quality"] or "", "; ".join(r["reasons"]),
        r["options"].get("method", ""), r["kind"], *[""] * SEGMENT_ONLY,
    ]  # fmt: skip
    dims, sigmas = r["dimensions_m"] or [None] * 3, r["dimension_sigmas_m"] or [None] * 3
    own = [
        _rounded(r["value"], sigma, f), units + "2" if area else units, *(_rounded(v, s, k) for v, s in zip(dims, sigmas)),
        *(_sigma(s, k) for s in sigmas), "; ".join(f"{x:.1f} {y:.1f}" for x, y in r["points"]),
    ]  # fmt: skip
    return middle, own


def _row(r: dict[str, Any], units: str, base_url: str) -> list[Any]:
    k = UNITS[units]
    created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(r["created"]))
    lead = [r["id"], created, r["name"], r["note"], r["source"], r.get("source_kind", ""), r.get("recording", ""), r["frame_id"],
            r.get("frame_index", ""), units]  # fmt: skip
    if r["kind"] == SEGMENT:
        middle, own = _segment_cells(r, k), [""] * (len(CSV_COLUMNS) - SHAPE_CELLS)
    else:
        middle, own = _shape_cells(r, k, units)
    return [*lead, *middle, f"{base_url}api/measurements/{r['id']}/color.png", r["kind"], *own]


def csv_chunks(batches: Iterable[Iterable[Mapping[str, Any]]], units: str = "m", base_url: str = "") -> Iterator[str]:
    """The CSV of ``batches`` (rows of the measurements table without the per-sample arrays, oldest
    first) as text chunks: the header, then one chunk per batch. ``units`` one of :data:`UNITS`
    (checked here, before the first chunk: a ValueError); ``frame_url`` is ``base_url`` + the route
    of the measurement's frame."""
    if units not in UNITS:
        raise ValueError(f"units must be one of {', '.join(UNITS)} (got {units!r})")
    return _csv_chunks(batches, units, base_url)


def _csv_chunks(batches: Iterable[Iterable[Mapping[str, Any]]], units: str, base_url: str) -> Iterator[str]:
    buf = io.StringIO()
    writer = csv_safe.writer(buf, lineterminator="\r\n")  # RFC 4180; a \r or \n inside a cell is then quoted
    writer.writerow(CSV_COLUMNS)
    for rows in batches:
        for r in rows:
            writer.writerow(_row(record(r), units, base_url))
        yield buf.getvalue()
        buf.seek(0)
        buf.truncate()
    if buf.tell():
        yield buf.getvalue()  # the header of an empty history


def json_chunks(batches: Iterable[Iterable[Mapping[str, Any]]]) -> Iterator[bytes]:
    """``{"measurements": [...]}`` of ``batches`` (rows of the measurements table, oldest first, with
    the per-sample arrays' stored JSON text as ``samples_json`` and ``support_json``) as UTF-8
    chunks, one per batch: each record as :func:`history.records.record` gives it, its arrays
    appended as stored."""
    yield b'{"measurements":['
    sep = b""
    for rows in batches:
        parts = []
        for r in rows:
            rec = record(r)
            head = json.dumps(rec, ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()
            if rec["kind"] == SEGMENT:
                # numbers and booleans only: dropping the stored separators' spaces leaves the same values
                arrays = f',"samples_px":{r["samples_json"].replace(", ", ",")},"support":{r["support_json"].replace(", ", ",")}}}'
                head = head[:-1] + arrays.encode()
            parts.append(sep + head)
            sep = b","
        yield b"".join(parts)
    yield b"]}"
