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
The CSV never writes the per-sample arrays, so its rows are read without them.

JSON (:func:`json_chunks`): ``{"measurements": [...]}``, every record with its per-sample arrays
copied as the JSON text the database holds, never decoded and encoded again.
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

UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0, "in": 1 / 0.0254}

CSV_COLUMNS = (
    "id", "created_utc", "name", "note", "source", "source_kind", "recording", "frame_id", "frame_index", "units", "distance", "uncertainty_1sigma",
    "interval_low", "interval_high", "quality", "reasons", "method", "fit", "basic_distance",
    "p1_x_px", "p1_y_px", "p2_x_px", "p2_y_px", "p1_X", "p1_Y", "p1_Z", "p2_X", "p2_Y", "p2_Z",
    "n_samples", "n_valid", "n_support", "gap_detected", "warnings", "frame_url",
)  # fmt: skip


def supported_decimals(sigma: float | None, factor: float) -> int:
    """Decimals that keep two significant digits of the 1-sigma uncertainty ``sigma`` (m) in a unit of
    ``factor`` per metre: more would be noise, fewer would hide the precision. 4 when unknown."""
    if sigma is None or not math.isfinite(sigma) or sigma <= 0:
        return 4
    return int(min(6, max(0, 1 - math.floor(math.log10(sigma * factor)))))


def _row(r: dict[str, Any], units: str, base_url: str) -> list[Any]:
    k = UNITS[units]
    dec = supported_decimals(r["uncertainty_m"], k)

    def length(v: Any) -> Decimal | str:
        # A Decimal is a number to the CSV writer (csv_safe leaves it, so -0.250 stays a negative
        # length) and keeps the rounding's trailing zeros, which a float would drop.
        return "" if v is None else Decimal(f"{float(v) * k:.{dec}f}")

    sigma = "" if r["uncertainty_m"] is None else f"{r['uncertainty_m'] * k:.2g}"
    lo, hi = (list(r.get("interval_m") or []) + [None, None])[:2]
    created = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(r["created"]))
    return [
        r["id"], created, r["name"], r["note"], r["source"], r.get("source_kind", ""), r.get("recording", ""), r["frame_id"],
        r.get("frame_index", ""), units,
        length(r["distance_m"]), sigma, length(lo), length(hi), r.get("quality", ""), "; ".join(r.get("reasons", [])),
        r["method"], r["fit"], length(r["basic_distance_m"]),
        *(Decimal(f"{v:.1f}") for v in (*r["p1"], *r["p2"])), *(length(v) for v in (*r["p1_m"], *r["p2_m"])),
        r["n_samples"], r["n_valid"], r["n_support"], int(r["gap_detected"]), "; ".join(r["warnings"]),
        f"{base_url}api/measurements/{r['id']}/color.png",
    ]  # fmt: skip


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
            head = json.dumps(record(r), ensure_ascii=False, allow_nan=False, separators=(",", ":")).encode()
            # numbers and booleans only: dropping the stored separators' spaces leaves the same values
            arrays = f',"samples_px":{r["samples_json"].replace(", ", ",")},"support":{r["support_json"].replace(", ", ",")}}}'.encode()
            parts.append(sep + head[:-1] + arrays)
            sep = b","
        yield b"".join(parts)
    yield b"]}"
