"""One group's result rows: what a worker does with a :class:`batch.tasks.TaskGroup`.

:func:`run_group` is the one per-group function of every executor (this process, a pool, Ray).
Steps: open the group's source once (kept open for the next group of the same source in this
process, :mod:`batch.readers`); read each frame once; measure every task on it; encode the rows
in the run's fixed schema (:mod:`batch.schema`) as one Parquet file. A segment is measured by
``measure.measure_distance``, a shape (height, path, area, box) by ``measure.measure_shape``, the
function the service calls. A task that fails becomes a
row with ``error``, ``error_type`` and, where a field is to blame, ``error_field``: an invalid task
(its own message), a source that cannot be opened (``source``), a frame that cannot be read
(``frame``), options that do not go together (``options``), a measurement error. A row holds the
task's columns, the options used (``opt_*``), every field of its answer's ``to_dict``
(:meth:`measure.Measurement.to_dict` for a segment, :func:`batch.schema.shape_columns` for a shape;
a field added later must be given its column there), the project version and where and when it ran.
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

from measure import Frame, MeasureError, measure_distance, measure_shape

from batch.readers import FrameReader, reader_for
from batch.schema import encode_rows, extra_column, measurement_column, result_schema, shape_columns
from batch.tasks import SEGMENT, Task, measure_options
from batch.tasktable import TaskGroup, TaskTable


def project_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("depthruler")
    except PackageNotFoundError:
        return "unknown"


def flatten(value: Any) -> Any:
    """A ``to_dict()`` value as a Parquet cell: scalars and lists stay (tuples become lists, lists of
    lists stay nested); NaN becomes None; a mapping becomes a JSON string (its keys may differ
    between rows)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, default=str)
    if isinstance(value, (list, tuple)):
        if value and isinstance(value[0], (list, tuple, dict)):
            return [flatten(v) for v in value]
        # the hot path (hundreds of samples per row): one pass, no call per element
        return [None if isinstance(v, float) and not math.isfinite(v) else v for v in value]
    return value


def task_row(task: Task, run: str, defaults: dict[str, Any]) -> dict[str, Any]:
    """The task's own columns of its result row (an unreadable cell of an invalid task is None)."""
    row: dict[str, Any] = {
        "task": task.index,
        "task_key": task.key(defaults),
        "source": task.source,
        "frame": task.frame if isinstance(task.frame, int) else None,  # a history frame's uid is in frame_uid
        "kind": task.kind,
        "p1_x": task.p1[0],
        "p1_y": task.p1[1],
        "p2_x": task.p2[0],
        "p2_y": task.p2[1],
        "points": None if task.points is None else [list(p) for p in task.points],
        "on": None if task.on is None else [list(p) for p in task.on],
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
        return {"error": f"options {task.options} over the run's {defaults}: {exc}", "error_type": type(exc).__name__, "error_field": "options"}
    out.update({f"opt_{k}": v for k, v in asdict(options).items()})
    if frame is None:
        return out
    try:
        if task.kind == SEGMENT:
            answer = {measurement_column(k): v for k, v in measure_distance(frame, task.p1, task.p2, options).to_dict().items()}  # type: ignore[arg-type]
        else:  # a valid shape task has its kind and clicks
            answer = shape_columns(measure_shape(frame, task.kind, task.points, task.on, options))  # type: ignore[arg-type]
    except Exception as exc:  # noqa: BLE001 — bad clicks (MeasureError) or a bug: this task's error row, not a lost run
        return {**out, "error": str(exc) or repr(exc), "error_type": type(exc).__name__}
    out.update((k, flatten(v)) for k, v in answer.items())
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
    schema = group.schema if group.schema is not None else result_schema(extras(group.tasks))
    return GroupResult(len(rows), sum(1 for r in rows if r["error"] is not None), encode_rows(rows, schema))


def extras(tasks: Iterable[Task] | TaskTable) -> dict[str, list[Any]]:
    """Each carried-through column of ``tasks`` and its values (for the run's result schema)."""
    if isinstance(tasks, TaskTable):
        return {k: [flatten(x) for x in v if x is not None] for k, v in tasks.extra.items()}
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
    reader: FrameReader | None = None
    open_error: Exception | None = None
    frame_key: Any = object()
    frame: Frame | None = None
    frame_error: Exception | None = None
    read_ms: float | None = None
    for task in group.tasks:
        row = task_row(task, group.run, group.defaults)
        row.update(version=version, worker=worker, error=None, error_type=None, error_field=None)
        if task.error:
            row.update(error=task.error, error_type="TaskError", error_field=task.error_field, frame_read_ms=None, finished=time.time())
            rows.append(row)
            continue
        if reader is None and open_error is None:
            try:
                reader = reader_for(group.source)
            except Exception as exc:  # noqa: BLE001 — any failure to open the source is every task's error row
                open_error = exc
        if reader is not None and task.frame != frame_key:
            frame_key, frame, frame_error = task.frame, None, None
            t0 = time.perf_counter()
            try:
                frame = reader.frame(task.frame)  # type: ignore[arg-type] — a valid task has its frame
            except Exception as exc:  # noqa: BLE001 — a missing or corrupt frame is its tasks' error row
                frame_error = exc
            read_ms = (time.perf_counter() - t0) * 1e3
        row["frame_read_ms"] = read_ms if reader is not None else None
        row.update(measure_task(task, frame, group.defaults))
        failure = open_error or frame_error
        if failure is not None and row["error"] is None:
            what = f"cannot open {group.source}" if open_error else f"cannot read frame {task.frame}"
            row.update(error=f"{what}: {failure}", error_type=type(failure).__name__, error_field="source" if open_error else "frame")
        row["finished"] = time.time()
        rows.append(row)
    return rows
