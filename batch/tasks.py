"""Measurement tasks for `depthruler batch`: read from a CSV/JSONL/Parquet table, checked, grouped.

A task table has one row per measurement with the columns

- ``source``: a recording folder, or a source spec that reads frames by index (``replay:DIR``,
  ``depthpng:DIR``, ``middlebury:DIR``, any kind `device` knows); relative paths are relative to
  the folder of the task table (so a table travels with its archive) and are made absolute here,
  because Ray workers do not share the caller's working directory;
- ``frame``: the 0-based frame index in that source;
- ``p1_x``, ``p1_y``, ``p2_x``, ``p2_y``: the clicked points in pixels of the colour image;
- optional option columns named after :class:`measure.MeasureOptions` fields (``method``,
  ``support_fraction``, ``window``, ``extension_px``, ``gap_detection``, ``seed``); an empty cell
  takes the run's default;
- any other column is carried through to the results untouched.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from measure import MeasureOptions

from batch.errors import BatchError

REQUIRED = ("source", "frame", "p1_x", "p1_y", "p2_x", "p2_y")
OPTION_FIELDS: dict[str, type] = {f.name: f.type for f in dataclasses.fields(MeasureOptions)}  # type: ignore[misc]
FILE_KINDS = ("replay", "depthpng", "middlebury", "video", "history")  # spec kinds whose target is a path
RANDOM_ACCESS_KINDS = ("replay", "history")  # a frame can be read without reading the ones before it
LIVE_KINDS = ("oak", "v4l2")  # cameras: frame i is whatever arrives, not a recorded frame


class TaskError(BatchError):
    """A task table that cannot be read or holds a bad row; names the file, row and column."""


@dataclass(frozen=True)
class Task:
    """One measurement to make. ``index`` is the row's position in the table (the key ``--resume``
    uses); ``frame`` is an int index, or a saved frame's uid for the service history; ``options``
    holds only the options the row sets (the run's defaults fill the rest)."""

    index: int
    source: str
    frame: int | str
    p1: tuple[float, float]
    p2: tuple[float, float]
    options: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def key(self, defaults: dict[str, Any] | None = None) -> str:
        """A digest of what the task measures (source, frame, points, its options over the run's
        ``defaults``): ``--resume`` checks that a row done by an earlier run is the same task."""
        options = sorted({**(defaults or {}), **self.options}.items())
        blob = json.dumps([self.source, self.frame, self.p1, self.p2, options], default=str)
        return hashlib.sha1(blob.encode()).hexdigest()[:16]


def source_kind(source: str) -> str:
    """The spec kind of ``source`` (``replay`` for a bare recording folder)."""
    head = source.partition("?")[0]
    kind, sep, _ = head.partition(":")
    return kind.lower() if sep and kind.lower() != "file" and len(kind) > 1 else "replay"


def normalise_source(source: str, base: Path) -> str:
    """``source`` as a spec with an absolute path: a bare folder becomes ``replay:/abs/folder``."""
    text = source.strip()
    if not text:
        raise TaskError("empty source; give a recording folder or a spec such as replay:DIR")
    head, q, query = text.partition("?")
    kind, sep, target = head.partition(":")
    live = kind.lower() in LIVE_KINDS and (sep or not (base / head).exists())
    if not sep or len(kind) == 1:  # a bare path (a one-letter "kind" is a Windows drive)
        kind, target = "replay", head
    if live:
        raise TaskError(f"source {text!r} is a live camera; a batch measures recorded frames: `depthruler record` it first")
    if kind.lower() in FILE_KINDS and target:
        p = Path(target).expanduser()
        target = str(p if p.is_absolute() else (base / p).resolve())
    return f"{kind.lower()}:{target}" + (q + query if query else "")


def parse_option(name: str, value: Any) -> Any:
    """One option cell converted to the type of its MeasureOptions field; None for an empty cell."""
    if value is None or (isinstance(value, float) and math.isnan(value)) or (isinstance(value, str) and not value.strip()):
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
            if f != int(f):
                raise ValueError("not a whole number")
            return int(f)
        if kind in ("float", float):
            return float(value)
        return str(value)
    except (TypeError, ValueError) as exc:
        raise TaskError(f"option {name}={value!r}: {exc}") from None


def measure_options(task_options: dict[str, Any], defaults: dict[str, Any]) -> MeasureOptions:
    """The MeasureOptions of a task: its own options over the run's defaults (MeasureError if bad)."""
    return MeasureOptions(**{**defaults, **task_options})


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a CSV, JSONL or Parquet table as dicts (by file suffix)."""
    if not path.is_file():
        raise TaskError(f"{path} does not exist; give a CSV, JSONL or Parquet table of tasks")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            with path.open(newline="") as fh:
                return list(csv.DictReader(fh))
        if suffix in (".jsonl", ".ndjson"):
            rows = []
            for n, line in enumerate(path.read_text().splitlines(), 1):
                if line.strip():
                    obj = json.loads(line)
                    if not isinstance(obj, dict):
                        raise TaskError(f"{path} line {n} is not a JSON object")
                    rows.append(obj)
            return rows
        if suffix in (".parquet", ".pq"):
            import pyarrow.parquet as pq

            return pq.read_table(path).to_pylist()
    except (OSError, UnicodeDecodeError, csv.Error, json.JSONDecodeError) as exc:
        raise TaskError(f"{path} cannot be read as {suffix[1:]}: {exc}") from exc
    except Exception as exc:  # pyarrow's errors have no common base worth naming here
        if type(exc).__module__.startswith("pyarrow"):
            raise TaskError(f"{path} cannot be read as Parquet: {exc}") from exc
        raise
    raise TaskError(f"{path}: unknown table type {suffix!r}; use .csv, .jsonl or .parquet")


def read_tasks(path: Path) -> list[Task]:
    """The tasks of a table (see the module docstring); TaskError names the first bad row."""
    rows = read_rows(path)
    if not rows:
        raise TaskError(f"{path} holds no task rows")
    missing = [c for c in REQUIRED if c not in rows[0]]
    if missing:
        raise TaskError(f"{path} lacks the column(s) {', '.join(missing)}; a task table needs {', '.join(REQUIRED)}")
    base = path.resolve().parent
    tasks = []
    for i, row in enumerate(rows):
        where = f"{path} row {i + 1}"
        try:
            frame = parse_frame(row["frame"])
            pts = [float(row[c]) for c in REQUIRED[2:]]
            if not all(math.isfinite(v) for v in pts):
                raise TaskError("p1_x, p1_y, p2_x, p2_y must be finite pixel coordinates")
            options = {k: v for k, v in ((k, parse_option(k, row[k])) for k in OPTION_FIELDS if k in row) if v is not None}
            source = normalise_source(str(row["source"] or ""), base)
        except TaskError as exc:
            raise TaskError(f"{where}: {exc}") from None
        except KeyError as exc:
            raise TaskError(f"{where} has no {exc.args[0]!r}; every row needs {', '.join(REQUIRED)}") from None
        except (TypeError, ValueError) as exc:
            raise TaskError(f"{where}: {exc}; frame must be a whole number and the points numbers") from None
        extra = {k: v for k, v in row.items() if k not in REQUIRED and k not in OPTION_FIELDS}
        tasks.append(Task(i, source, frame, (pts[0], pts[1]), (pts[2], pts[3]), options, extra))
    return tasks


def parse_frame(value: Any) -> int:
    """A ``frame`` cell as a 0-based index (``3``, ``"3"`` and ``3.0`` are frame 3)."""
    f = float(value)
    if f != int(f) or f < 0:
        raise TaskError(f"frame={value!r} must be a frame index (a whole number >= 0)")
    return int(f)


@dataclass(frozen=True)
class TaskGroup:
    """Tasks of one source, in frame order, for one worker call; ``defaults`` are the run's options."""

    source: str
    tasks: tuple[Task, ...]
    defaults: dict[str, Any] = field(default_factory=dict)
    run: str = ""
    schema: Any = None  # the run's pyarrow result schema (batch.schema); None: built from these tasks


def group_tasks(
    tasks: list[Task], workers: int, defaults: dict[str, Any], run: str = "", max_group: int = 256, schema: Any = None
) -> list[TaskGroup]:
    """Tasks grouped by source, each group sorted by frame so every frame is read once.

    A random-access source (a recording, the history) is cut further, at frame boundaries, into
    groups of at most ``max_group`` tasks and at least enough groups to keep ``workers`` busy four
    times over: results then stream to disk as groups finish, and the load balances. A source read
    in order (a depth-PNG folder, a video) stays one group, or frames would be decoded twice.
    """
    by_source: dict[str, list[Task]] = {}
    for t in tasks:
        by_source.setdefault(t.source, []).append(t)
    target = max(1, min(max_group, math.ceil(len(tasks) / max(1, 4 * workers))))
    groups: list[TaskGroup] = []
    for source, items in by_source.items():
        items.sort(key=lambda t: (str(type(t.frame)), t.frame, t.index))
        if source_kind(source) not in RANDOM_ACCESS_KINDS:
            groups.append(TaskGroup(source, tuple(items), defaults, run, schema))
            continue
        chunk: list[Task] = []
        for t in items:
            if len(chunk) >= target and t.frame != chunk[-1].frame:
                groups.append(TaskGroup(source, tuple(chunk), defaults, run, schema))
                chunk = []
            chunk.append(t)
        if chunk:
            groups.append(TaskGroup(source, tuple(chunk), defaults, run, schema))
    # The biggest first: a long group started last would leave the other workers idle at the end.
    groups.sort(key=lambda g: len(g.tasks), reverse=True)
    return groups
