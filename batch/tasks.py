"""Measurement tasks for `depthruler batch`: read from a CSV/JSONL/Parquet table, checked row by row, grouped.

A task table has one row per measurement with the columns

- ``source``: a recording folder, or a source spec that reads frames by index (``replay:DIR``,
  ``depthpng:DIR``, ``middlebury:DIR``, any kind `device` knows); relative paths are relative to
  the folder of the task table and are made absolute here (Ray workers do not share the caller's
  working directory);
- ``frame``: the 0-based frame index in that source, a whole number from 0 to 2^53 - 1;
- ``kind`` (optional): ``segment`` (an empty cell, or no column) or a shape, ``height``, ``path``,
  ``area``, ``box``;
- a segment's clicks ``p1_x``, ``p1_y``, ``p2_x``, ``p2_y``: finite pixels of the colour image;
- a shape's clicks ``points``: ``[[x, y], ...]`` as JSON text (or a list, in JSONL and Parquet): one
  for a box or a height, two or more for a path, three or more for an area, in order; ``on``
  likewise, a height's base plane (one click on it, or three or more around it; empty: the plane
  the object stands on);
- optional option columns named after :class:`measure.MeasureOptions` fields (``method``,
  ``support_fraction``, ``window``, ``extension_px``, ``gap_detection``, ``seed``, ``click_px``:
  docs/usage.md "Measure options"); an empty cell takes the run's default;
- any other column is carried through to the results untouched.

:func:`read_tasks` reads the table (a CSV's byte-order mark, as Excel writes it, is skipped) and
refuses it only when it cannot be read, holds no row or lacks a required column. Each row is then
checked on its own: a bad cell (an empty or NaN pixel, a frame beyond 2^53 - 1, an empty or live
source, an unknown kind, clicks that are no JSON list of pairs or too few for the kind, a bad
option, a JSONL line that is no object) makes an *invalid* task whose ``error`` names the field
and what to write; it becomes an error row and the other rows are measured.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import hashlib
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from measure import SHAPE_KINDS, MeasureError, MeasureOptions

from batch.errors import BatchError

if TYPE_CHECKING:
    from batch.tasktable import TaskTable

REQUIRED = ("source", "frame", "p1_x", "p1_y", "p2_x", "p2_y")  # a table of shapes only: source, frame, kind and points
POINT_COLUMNS = REQUIRED[2:]
SEGMENT = "segment"
KINDS = (SEGMENT, *SHAPE_KINDS)
SHAPE_COLUMNS = ("kind", "points", "on")
LEAST_CLICKS = {"box": 1, "height": 1, "path": 2, "area": 3}
MAX_FRAME = 2**53 - 1  # the largest whole number a float64 (and so JSON and JavaScript) holds exactly
OPTION_FIELDS: dict[str, type] = {f.name: f.type for f in dataclasses.fields(MeasureOptions)}  # type: ignore[misc]
FILE_KINDS = ("replay", "depthpng", "middlebury", "video", "history")  # spec kinds whose target is a path
RANDOM_ACCESS_KINDS = ("replay", "history")  # a frame can be read without reading the ones before it
LIVE_KINDS = ("oak", "v4l2")  # cameras: frame i is whatever arrives, not a recorded frame
PARQUET_BATCH_ROWS = 4096  # a Parquet table's rows become dicts this many at a time (~2 MB of them)


class TaskError(BatchError):
    """A task table that cannot be read, or one bad cell of a row; names the file, row or column."""


@dataclass(frozen=True, slots=True)
class Task:
    """One measurement to make. ``index`` is the row's position in the table (the key ``--resume``
    uses); ``frame`` is an int index, or a saved frame's uid for the service history; ``options``
    holds only the options the row sets (the run's defaults fill the rest). An invalid task has
    ``error`` (what is wrong and what to write) and ``error_field`` (the column(s), comma-separated);
    its unreadable cells are None."""

    index: int
    source: str
    frame: int | str | None
    p1: tuple[float | None, float | None]
    p2: tuple[float | None, float | None]
    options: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    error_field: str | None = None
    kind: str | None = SEGMENT  # None: the kind cell could not be read
    points: tuple[tuple[float, float], ...] | None = None
    on: tuple[tuple[float, float], ...] | None = None

    def key(self, defaults: dict[str, Any] | None = None) -> str:
        """A digest of what the task measures (source, frame, kind, clicks, its options over the run's
        ``defaults``): ``--resume`` checks that a row done by an earlier run is the same task."""
        options = sorted({**(defaults or {}), **self.options}.items())
        what: list[Any] = [self.source, self.frame, self.p1, self.p2, options]
        if self.kind != SEGMENT:  # a segment's digest is the one runs made before shapes
            what += [self.kind, self.points, self.on]
        if self.error:
            what.append(self.error)
        return hashlib.sha1(json.dumps(what, default=str).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class BadLine:
    """A line of a JSONL table that is no JSON object: its row's error."""

    message: str


def source_kind(source: str) -> str:
    """The spec kind of ``source`` (``replay`` for a bare recording folder or a recording URL)."""
    from batch.remote import is_url

    head = source.partition("?")[0]
    if is_url(head):
        return "replay"
    kind, sep, _ = head.partition(":")
    return kind.lower() if sep and kind.lower() != "file" and len(kind) > 1 else "replay"


def normalise_source(source: str, base: Path | str) -> str:
    """``source`` as a spec with an absolute path or URL: a bare folder becomes ``replay:/abs/folder``;
    ``base`` is the table's folder (a local path, or a URL for a table on object storage)."""
    from batch.remote import is_url, join

    text = source.strip()
    if not text:
        raise TaskError("source is empty; give a recording folder or a spec such as replay:DIR")
    head, q, query = text.partition("?")
    kind, sep, target = head.partition(":")
    if is_url(head) or (kind.lower() == "replay" and is_url(target)):
        return "replay:" + (head if is_url(head) else target) + (q + query if query else "")
    if isinstance(base, str):  # a table on object storage: its relative folders are beside it there
        if sep and len(kind) > 1:
            raise TaskError(f"source {shown(text)}: a table on object storage names recordings by URL or by a folder relative to it")
        return "replay:" + join(base, head) + (q + query if query else "")
    live = kind.lower() in LIVE_KINDS and (sep or not (base / head).exists())
    if not sep or len(kind) == 1:  # a bare path (a one-letter "kind" is a Windows drive)
        kind, target = "replay", head
    if live:
        raise TaskError(f"source {shown(text)} is a live camera; a batch measures recorded frames: `depthruler record` it first")
    if kind.lower() in FILE_KINDS and target:
        p = Path(target).expanduser()
        target = str(p if p.is_absolute() else (base / p).resolve())
    return f"{kind.lower()}:{target}" + (q + query if query else "")


@functools.lru_cache(maxsize=4096)
def _normalised(source: str, base: Path | str) -> str:
    """:func:`normalise_source`, once per distinct source of a table (a table names few recordings
    many times, and each call touches the filesystem)."""
    return normalise_source(source, base)


def shown(value: Any, limit: int = 40) -> str:
    """``repr(value)``, cut to ``limit`` characters (a 5000-digit cell does not fill the error message)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _empty(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value)) or (isinstance(value, str) and not value.strip())


def parse_option(name: str, value: Any) -> Any:
    """One option cell converted to the type of its MeasureOptions field; None for an empty cell."""
    if _empty(value):
        return None
    kind = OPTION_FIELDS[name]
    try:
        if kind in ("bool", bool):
            if isinstance(value, bool):
                return value
            text = str(value).strip().lower()
            if text in ("1", "true", "yes", "on"):
                return True
            if text in ("0", "false", "no", "off"):
                return False
            raise ValueError("not a yes/no value (1/0, true/false)")
        if kind in ("int", int):
            f = float(value)
            if not f.is_integer():
                raise ValueError("not a whole number")
            return int(f)
        if kind in ("float", float):
            return float(value)
        return str(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise TaskError(f"option {name}={shown(value)}: {exc}") from None


def measure_options(task_options: dict[str, Any], defaults: dict[str, Any]) -> MeasureOptions:
    """The MeasureOptions of a task: its own options over the run's defaults (MeasureError if bad)."""
    return MeasureOptions(**{**defaults, **task_options})


def parse_frame(value: Any) -> int:
    """A ``frame`` cell as a 0-based index (``3``, ``"3"`` and ``3.0`` are frame 3), at most :data:`MAX_FRAME`."""
    if _empty(value):
        raise TaskError("frame is empty; give the 0-based frame index")
    wrong = TaskError(f"frame={shown(value)} must be a frame index, a whole number from 0 to 2^53 - 1 ({MAX_FRAME})")
    if isinstance(value, bool):
        raise wrong
    if isinstance(value, int):
        n = value
    else:
        try:
            n = int(str(value).strip())  # exact for integer text of any length
        except ValueError:
            try:
                f = float(value)
            except (TypeError, ValueError):
                raise wrong from None
            if not (math.isfinite(f) and f.is_integer()):
                raise wrong from None
            n = int(f)
    if not 0 <= n <= MAX_FRAME:
        raise wrong
    return n


def parse_pixel(name: str, value: Any) -> float:
    """One point cell as a finite pixel coordinate."""
    if _empty(value):
        raise TaskError(f"{name} is empty; give the pixel coordinate of the click")
    try:
        if isinstance(value, bool):
            raise ValueError
        f = float(value)
    except (TypeError, ValueError, OverflowError):
        raise TaskError(f"{name}={shown(value)} is not a number; give the pixel coordinate of the click") from None
    if not math.isfinite(f):
        raise TaskError(f"{name}={shown(value)} must be a finite pixel coordinate")
    return f


def parse_kind(value: Any) -> str:
    """A ``kind`` cell: "segment" when empty, else one of :data:`KINDS` (any case)."""
    if _empty(value):
        return SEGMENT
    kind = str(value).strip().lower()
    if kind not in KINDS:
        raise TaskError(f"kind={shown(value)} is not a kind of measurement; write one of {', '.join(KINDS)} (empty: segment)")
    return kind


def _pair(p: Any) -> tuple[float, float]:
    if not isinstance(p, (list, tuple)) or len(p) != 2 or any(v is None or isinstance(v, (bool, str)) for v in p):
        raise ValueError
    return float(p[0]), float(p[1])


def no_clicks(value: Any) -> bool:
    """An empty ``points`` or ``on`` cell: nothing, blank text, ``[]`` or ``null``."""
    if isinstance(value, (list, tuple)):
        return not value
    return _empty(value) or (isinstance(value, str) and value.strip().lower() in ("[]", "null"))


def parse_clicks(name: str, value: Any, least: int, most: int | None = None, what: str = "this kind") -> tuple[tuple[float, float], ...]:
    """A ``points`` or ``on`` cell: JSON text ``[[x, y], ...]`` or a list of pairs, finite pixels,
    ``least`` to ``most`` of them (``what`` takes them, for the message)."""
    if no_clicks(value):
        raise TaskError(f"{name} is empty; give the clicks as JSON [[x, y], ...]")
    pairs = value
    if isinstance(value, str):
        try:
            pairs = json.loads(value)
        except (json.JSONDecodeError, RecursionError):
            raise TaskError(f"{name}={shown(value)} is not JSON; write the clicks as [[x, y], ...]") from None
    try:
        if not isinstance(pairs, (list, tuple)):
            raise ValueError
        clicks = tuple(_pair(p) for p in pairs)
    except (TypeError, ValueError, OverflowError):
        raise TaskError(f"{name}={shown(value)} must be a list of [x, y] pixel pairs, e.g. [[120, 80], [300, 95]]") from None
    if not all(math.isfinite(v) for p in clicks for v in p):
        raise TaskError(f"{name}={shown(value)} holds a coordinate that is not finite; give finite pixels")
    if len(clicks) < least or (most is not None and len(clicks) > most):
        count = f"exactly {least}" if most == least else f"at least {least}"
        raise TaskError(f"{name} holds {len(clicks)} click(s); {what} takes {count}")
    return clicks


def read_rows(path: Path, row_groups: list[int] | None = None) -> Iterator[dict[str, Any] | BadLine]:
    """The rows of a CSV, JSONL or Parquet table as dicts (by file suffix), one at a time (a table of
    a million rows is never held as dicts); a JSONL line that is no JSON object is a :class:`BadLine`;
    ``row_groups`` reads only those row groups of a Parquet table. TaskError when the file cannot be
    read, also part way through."""
    if not path.is_file():
        raise TaskError(f"{path} does not exist; give a CSV, JSONL or Parquet table of tasks")
    suffix = path.suffix.lower()
    if suffix not in (".csv", ".jsonl", ".ndjson", ".parquet", ".pq"):
        raise TaskError(f"{path}: unknown table type {suffix!r}; use .csv, .jsonl or .parquet")
    return _rows(path, suffix, row_groups)


def _rows(path: Path, suffix: str, row_groups: list[int] | None = None) -> Iterator[dict[str, Any] | BadLine]:
    try:
        if suffix == ".csv":
            with path.open(newline="", encoding="utf-8-sig") as fh:
                yield from csv.DictReader(fh)
        elif suffix in (".jsonl", ".ndjson"):
            with path.open(encoding="utf-8-sig") as fh:
                for n, line in enumerate(fh, 1):
                    if line.strip():
                        try:
                            obj = json.loads(line)
                        except (json.JSONDecodeError, RecursionError) as exc:
                            obj = exc
                        yield obj if isinstance(obj, dict) else BadLine(f"line {n} is not a JSON object ({obj}); write one object per line")
        else:
            import pyarrow.parquet as pq

            for batch in pq.ParquetFile(path).iter_batches(batch_size=PARQUET_BATCH_ROWS, row_groups=row_groups):
                yield from batch.to_pylist()
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise TaskError(f"{path} cannot be read as {suffix[1:]}: {exc}") from exc
    except Exception as exc:  # pyarrow's errors have no common base worth naming here
        if type(exc).__module__.startswith("pyarrow"):
            raise TaskError(f"{path} cannot be read as Parquet: {exc}") from exc
        raise


@dataclass(frozen=True)
class TableFile:
    """A task table to be read where the work runs (by Ray Data's workers), not in this process: its
    ``location`` (an absolute local path or a URL) and ``base``, the folder its relative sources are in."""

    location: str
    base: Path | str

    @staticmethod
    def at(path: Path | str) -> TableFile:
        from batch.remote import is_url, parent

        if isinstance(path, str) and is_url(path):
            return TableFile(path, parent(path))
        p = Path(path).resolve()
        return TableFile(str(p), p.parent)


def read_tasks(path: Path | str | TableFile) -> TaskTable:
    """The tasks of a table, one per row, as columns (:class:`batch.tasktable.TaskTable`), invalid ones included (see the module docstring); ``path``
    may be a URL (:mod:`batch.remote`), whose relative sources are then read beside it."""
    from batch.remote import fetch_table, is_url, parent

    if isinstance(path, TableFile):
        path = path.location
    if isinstance(path, str) and is_url(path):
        import tempfile

        with tempfile.TemporaryDirectory() as folder:
            return _tasks(read_rows(fetch_table(path, Path(folder))), parent(path), path)
    path = Path(path)
    return _tasks(read_rows(path), path.resolve().parent, path)


def _tasks(rows: Iterable[dict[str, Any] | BadLine], base: Path | str, where: Path | str) -> TaskTable:
    """Each row parsed as it is read into columns (no row kept as an object); the table refused
    when it holds no row or lacks a required column."""
    from batch.tasktable import TaskColumns

    tasks = TaskColumns()
    columns: set[str] = set()
    for i, row in enumerate(rows):
        if isinstance(row, dict) and not columns.issuperset(row):
            columns.update(k for k in row if k is not None)
        tasks.add(parse_row(i, row, base))
    check_table(columns, len(tasks.index), where)
    return tasks.table()


def check_table(columns: set[str], rows: int, where: Path | str) -> None:
    """TaskError when a table of ``rows`` rows with ``columns`` cannot be a task table: no row, or a
    required column missing."""
    if not rows:
        raise TaskError(f"{where} holds no task rows")
    missing = [c for c in REQUIRED if c not in columns and (c in REQUIRED[:2] or "points" not in columns)]
    if missing:
        raise TaskError(
            f"{where} lacks the column(s) {', '.join(missing)}; a task table needs {', '.join(REQUIRED)} "
            "(a table of shapes only: source, frame, kind and points)"
        )


def row_extra(row: dict[str, Any]) -> dict[str, Any]:
    """The cells of ``row`` carried through to the results: every column that is no task column."""
    return {k: v for k, v in row.items() if k is not None and k not in REQUIRED and k not in SHAPE_COLUMNS and k not in OPTION_FIELDS}


def cell_text(value: Any) -> str:
    """A cell as text ("" when empty)."""
    return "" if _empty(value) else str(value)


def task_place(row: dict[str, Any], base: Path | str) -> tuple[str, int | None]:
    """Where the task of ``row`` measures, as :func:`parse_row` gives it, without parsing the rest:
    its source (normalised, or the cell's text when that fails) and its frame (None when unreadable)."""
    try:
        source = _normalised(cell_text(row.get("source")), base)
    except TaskError:
        source = cell_text(row.get("source"))
    try:
        frame: int | None = parse_frame(row.get("frame"))
    except TaskError:
        frame = None
    return source, frame


def parse_row(index: int, row: dict[str, Any] | BadLine, base: Path | str) -> Task:
    """The task of one table row; a bad cell makes it invalid (``error`` names every bad field)."""
    if isinstance(row, BadLine):
        return Task(index, "", None, (None, None), (None, None), error=row.message, error_field="row", kind=None)
    bad: dict[str, str] = {}

    def check(name: str, parse, value: Any) -> Any:  # noqa: ANN001 — one of the parsers above
        try:
            return parse(value)
        except TaskError as exc:
            bad[name] = str(exc)
            return None

    frame = check("frame", parse_frame, row.get("frame"))
    kind = check("kind", parse_kind, row.get("kind"))
    pts: list[float | None] = [None] * 4
    points = on = None
    if kind == SEGMENT:
        pts = [check(c, lambda v, c=c: parse_pixel(c, v), row.get(c)) for c in POINT_COLUMNS]
        for c in SHAPE_COLUMNS[1:]:
            if not no_clicks(row.get(c)):
                bad[c] = f"{c} holds the clicks of a shape; a segment's are p1_x, p1_y, p2_x, p2_y (set kind to {', '.join(SHAPE_KINDS)})"
    elif kind is not None:
        least = LEAST_CLICKS[kind]
        points = check("points", lambda v: parse_clicks("points", v, least, least if least == 1 else None, f"a {kind}"), row.get("points"))
        if kind == "height" and not no_clicks(row.get("on")):
            on = check("on", lambda v: parse_clicks("on", v, 1, what="a height's base"), row.get("on"))
            if on is not None and len(on) == 2:
                bad["on"], on = "on holds 2 clicks; give 1 click on the base plane or 3 or more around a region of it", None
        elif not no_clicks(row.get("on")):
            bad["on"] = f"on names the base plane of a height; leave it empty for a {kind}"
    options = {}
    for name in OPTION_FIELDS:
        value = check(name, lambda v, name=name: parse_option(name, v), row.get(name))
        if value is None:
            continue
        try:
            MeasureOptions(**{name: value})
        except MeasureError as exc:
            bad[name] = f"option {exc}"
            continue
        options[name] = value
    source = check("source", lambda v: _normalised("" if _empty(v) else str(v), base), row.get("source"))
    if None in row:  # csv.DictReader keeps a row's cells beyond the header under the key None
        bad["row"] = f"the row has {len(row[None])} more cell(s) than the header; quote cells that hold commas"
    return Task(
        index, source if source is not None else cell_text(row.get("source")), frame,
        (pts[0], pts[1]), (pts[2], pts[3]), options, row_extra(row),
        error="; ".join(bad.values()) or None, error_field=",".join(bad) or None, kind=kind, points=points, on=on,
    )  # fmt: skip
