"""Batch re-measurement: run task groups on an executor, one result row per task.

A worker (:func:`run_group`) opens the group's source once (kept open for the next group of the
same source in that process), reads each frame once, and measures every task on it; a task that fails
(a missing frame, a bad option, a measurement error) becomes a row with ``error`` set, so a run is
never lost to one bad task. Result rows hold the task's columns, the options used, the full
:class:`measure.Measurement` (every field of ``to_dict()``, so fields added later flow through),
the project version the worker ran and where and when it ran.
"""

from __future__ import annotations

import math
import os
import socket
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol

from measure import Frame, MeasureError, MeasureOptions, measure_distance

from batch.schema import encode_rows, extra_column, measurement_column, result_schema
from batch.tasks import Task, TaskError, TaskGroup, group_tasks, measure_options, source_kind

_READER_CACHE = 2  # open sources kept per worker process


def project_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("depthruler")
    except PackageNotFoundError:
        return "unknown"


class FrameReader(Protocol):
    def frame(self, key: int | str) -> Frame: ...

    def close(self) -> None: ...


class RecordingFrames:
    """A recording folder, read by index (a frame costs only its own files)."""

    def __init__(self, path: str) -> None:
        from device.formats.recording import open_recording

        self.rec = open_recording(path)

    def frame(self, key: int | str) -> Frame:
        i = int(key)
        if not 0 <= i < len(self.rec):
            raise TaskError(f"frame {i} is not in {self.rec.path}: it holds {len(self.rec)} complete frames (0-{len(self.rec) - 1})")
        return self.rec.frame(i)

    def close(self) -> None:
        pass


class SequentialFrames:
    """Any source spec read in order: frame ``i`` is the ``i``-th ``read()`` after opening. Asking for
    an earlier frame than the last one reopens the source (groups ask in ascending order)."""

    def __init__(self, spec: str) -> None:
        from device import make_source

        self.spec = spec
        self.src = make_source(spec)
        self.src.open()
        self.pos = -1
        self.last: Frame | None = None

    def frame(self, key: int | str) -> Frame:
        from device import SourceEnded

        i = int(key)
        if i < self.pos:
            self.src.close()
            self.src.open()
            self.pos, self.last = -1, None
        while self.pos < i:
            try:
                self.last = self.src.read(timeout_s=60.0)
            except SourceEnded:
                raise TaskError(f"frame {i} is not in {self.spec}: it ended after {self.pos + 1} frames") from None
            self.pos += 1
        assert self.last is not None
        return self.last

    def close(self) -> None:
        self.src.close()


def open_reader(source: str) -> FrameReader:
    kind = source_kind(source)
    if kind == "history":
        from batch.history import HistoryFrames

        return HistoryFrames(Path(source.partition(":")[2]))
    if kind == "replay":
        from device import SourceSpec

        spec = SourceSpec.parse(source)
        if not spec.params:  # replay options (start, loop) change what index i means: read in order then
            return RecordingFrames(spec.target)
    return SequentialFrames(source)


_readers: OrderedDict[str, FrameReader] = OrderedDict()


def reader_for(source: str) -> FrameReader:
    """This process's open reader of ``source``; the least recently used one closes past the cache size."""
    reader = _readers.pop(source, None)
    if reader is None:
        reader = open_reader(source)
    _readers[source] = reader
    while len(_readers) > _READER_CACHE:
        _, old = _readers.popitem(last=False)
        old.close()
    return reader


def close_readers() -> None:
    while _readers:
        _readers.popitem()[1].close()


def flatten(value: Any) -> Any:
    """A ``to_dict()`` value as a Parquet cell: scalars and lists stay (tuples become lists, lists of
    lists stay nested); NaN becomes None; a mapping becomes a JSON string (its keys may differ
    between rows)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        import json

        return json.dumps(value, sort_keys=True, default=str)
    if isinstance(value, (list, tuple)):
        if value and isinstance(value[0], (list, tuple, dict)):
            return [flatten(v) for v in value]
        # the hot path (hundreds of samples per row): one pass, no call per element
        return [None if isinstance(v, float) and not math.isfinite(v) else v for v in value]
    return value


def task_row(task: Task, run: str, defaults: dict[str, Any]) -> dict[str, Any]:
    row: dict[str, Any] = {
        "task": task.index,
        "task_key": task.key(defaults),
        "source": task.source,
        "frame": task.frame if isinstance(task.frame, int) else None,  # a history frame's uid is in frame_uid
        "p1_x": float(task.p1[0]),
        "p1_y": float(task.p1[1]),
        "p2_x": float(task.p2[0]),
        "p2_y": float(task.p2[1]),
        "run": run,
    }
    for k, v in task.extra.items():
        row[extra_column(k)] = flatten(v)
    return row


def measure_task(task: Task, frame: Frame | None, defaults: dict[str, Any]) -> dict[str, Any]:
    """The measurement columns of one task: ``opt_*`` options and the Measurement's fields, or
    ``error``. ``frame`` None means it could not be read (the caller sets the error)."""
    out: dict[str, Any] = {}
    try:
        options = measure_options(task.options, defaults)
    except (MeasureError, TypeError) as exc:
        return {"error": f"options {task.options}: {exc}", "error_type": type(exc).__name__}
    out.update({f"opt_{k}": v for k, v in asdict(options).items()})
    if frame is None:
        return out
    try:
        m = measure_distance(frame, task.p1, task.p2, options)
    except Exception as exc:  # noqa: BLE001 — bad clicks (MeasureError) or a bug: this task's error row, not a lost run
        return {**out, "error": str(exc) or repr(exc), "error_type": type(exc).__name__}
    for k, v in m.to_dict().items():
        out[measurement_column(k)] = flatten(v)
    return out


@dataclass(frozen=True)
class GroupResult:
    """What a worker sends back for a group: its rows already encoded as one Parquet file, so the
    caller only writes bytes (with many workers the caller is the bottleneck), and two counts."""

    rows: int
    errors: int
    parquet: bytes


def run_group(group: TaskGroup) -> GroupResult:
    """Measure a group (worker side) and encode its rows in the run's schema; never raises for a bad task or source."""
    rows = measure_group(group)
    schema = group.schema if group.schema is not None else result_schema(_extras(group.tasks))
    return GroupResult(len(rows), sum(1 for r in rows if r["error"] is not None), encode_rows(rows, schema))


def _extras(tasks: Iterable[Task]) -> dict[str, list[Any]]:
    """Each carried-through column of ``tasks`` and its values (for the run's result schema)."""
    cols: dict[str, list[Any]] = {}
    for t in tasks:
        for k, v in t.extra.items():
            cols.setdefault(k, []).append(flatten(v))
    return cols


def measure_group(group: TaskGroup) -> list[dict[str, Any]]:
    """One result row per task of a group, in the group's order (see the module docstring)."""
    version = project_version()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    rows: list[dict[str, Any]] = []
    try:
        reader: FrameReader | None = reader_for(group.source)
        open_error: Exception | None = None
    except Exception as exc:  # noqa: BLE001 — any failure to open the source is every task's error row
        reader, open_error = None, exc
    frame_key: Any = object()
    frame: Frame | None = None
    frame_error: Exception | None = None
    read_ms = 0.0
    for task in group.tasks:
        if reader is not None and task.frame != frame_key:
            frame_key, frame, frame_error = task.frame, None, None
            t0 = time.perf_counter()
            try:
                frame = reader.frame(task.frame)
            except Exception as exc:  # noqa: BLE001 — a missing or corrupt frame is its tasks' error row
                frame_error = exc
            read_ms = (time.perf_counter() - t0) * 1e3
        row = task_row(task, group.run, group.defaults)
        row.update(version=version, worker=worker, frame_read_ms=read_ms if reader is not None else None)
        row.update(measure_task(task, frame, group.defaults))
        failure = open_error or frame_error
        if failure is not None and "error" not in row:
            row["error"] = f"{'cannot open ' + group.source if open_error else 'cannot read frame ' + str(task.frame)}: {failure}"
            row["error_type"] = type(failure).__name__
        row.setdefault("error", None)
        row.setdefault("error_type", None)
        row["finished"] = time.time()
        rows.append(row)
    return rows


class Sink(Protocol):
    def write(self, parquet: bytes) -> None: ...


def run_tasks(executor: Any, groups: list[TaskGroup], sink: Sink, on_group: Callable[[GroupResult], None] | None = None) -> int:
    """Run ``groups`` on ``executor``, writing each group's rows to ``sink`` as it finishes; the
    number of rows written."""
    n = 0
    for _, result in executor.imap(run_group, groups):
        sink.write(result.parquet)
        n += result.rows
        if on_group:
            on_group(result)
    return n


def default_options(pairs: Iterable[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (``--set``) as MeasureOptions defaults; TaskError names a bad one."""
    from batch.tasks import OPTION_FIELDS, parse_option

    out: dict[str, Any] = {}
    for text in pairs:
        key, sep, value = text.partition("=")
        key = key.strip()
        if not sep or key not in OPTION_FIELDS:
            raise TaskError(f"--set {text!r}: write KEY=VALUE with KEY one of {', '.join(OPTION_FIELDS)}")
        out[key] = parse_option(key, value)
    try:
        MeasureOptions(**out)
    except MeasureError as exc:
        raise TaskError(f"--set: {exc}") from None
    return out


def run_batch(
    tasks: list[Task],
    out: Path,
    executor: Any,
    *,
    defaults: dict[str, Any] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[int, int], None] | None = None,
    on_group: Callable[[GroupResult], None] | None = None,
) -> dict[str, Any]:
    """Measure ``tasks`` on ``executor`` into the Parquet file ``out``; a summary dict.

    ``on_start(to_do, already_done)`` is called before the first group runs. With ``resume`` the
    tasks already in ``out`` or its parts are skipped (ResultsError if one of them is no longer the
    same task: the table changed since that run)."""
    import json
    import uuid

    from batch.results import ResultsError, ResultStore

    defaults = dict(defaults or {})
    store = ResultStore(out, resume=resume, overwrite=overwrite)
    done = store.done()
    changed = [t.index for t in tasks if t.index in done and done[t.index] != t.key(defaults)]
    if changed:
        raise ResultsError(
            f"{len(changed)} task(s) (first: row {changed[0] + 1}) differ from the ones {out} holds for those rows; "
            "the task table or the --set options changed since that run: use --overwrite"
        )
    todo = [t for t in tasks if t.index not in done]
    run = uuid.uuid4().hex[:12]
    groups = group_tasks(todo, getattr(executor, "workers", 1), defaults, run, schema=result_schema(_extras(tasks)))
    if on_start:
        on_start(len(todo), len(tasks) - len(todo))
    t0 = time.perf_counter()
    try:
        n = run_tasks(executor, groups, store, on_group)
    finally:
        close_readers()  # the in-process executor's sources: a later run must see the archive as it is then
    wall = time.perf_counter() - t0
    total = store.finish(
        {"depthruler.version": project_version(), "depthruler.defaults": json.dumps(defaults), "depthruler.executor": executor.describe()}
    )
    return {"run": run, "measured": n, "skipped": len(tasks) - len(todo), "rows": total, "groups": len(groups), "wall_s": wall}

