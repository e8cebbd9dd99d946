"""Tasks held as columns, and their groups: what the driver keeps of a task table.

A :class:`batch.tasks.Task` is a Python object of ~830 bytes; a million of them would be most of a
driver's memory. :class:`TaskTable` keeps the same tasks as numpy columns (~80 bytes a task: row
index, source code, frame, kind code, four pixels, options code, error and error field; a shape's
clicks only in a table that holds shapes) and builds a ``Task``
only when one is asked for, so the driver never holds the table as objects and a group crosses to
a worker as a few arrays. :func:`group_tasks` sorts and cuts those columns into
:class:`TaskGroup` slices; a worker iterates its group's tasks one at a time.
"""

from __future__ import annotations

import json
import math
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from batch.tasks import KINDS, RANDOM_ACCESS_KINDS, Task, source_kind

NO_FRAME = -1  # the frame column of a task whose frame cell could not be read
NO_KIND = -1  # the kind column of a task whose kind cell could not be read


def _key(options: dict[str, Any]) -> str:
    return json.dumps(sorted(options.items()), default=str)


class TaskColumns:
    """Builds a :class:`TaskTable` one task at a time in compact arrays (no list of objects per
    number); sources, option sets and carried-through column names are stored once each."""

    def __init__(self) -> None:
        self.index, self.source, self.option = array("q"), array("i"), array("i")
        self.kind = array("b")
        self.points = array("d")
        self.shapes: list[tuple[int, Any, Any]] = []  # (row, points, on) of the shape tasks
        self.frames: list[Any] | array = array("q")
        self.errors: list[tuple[int, str, str | None]] = []  # (row, error, error field): invalid rows are few
        self.sources: dict[str, int] = {}
        self.options: dict[str, tuple[int, dict[str, Any]]] = {}
        self.extra: dict[str, list[Any]] = {}

    def add(self, t: Task) -> None:
        n = len(self.index)
        self.index.append(t.index)
        self.source.append(self.sources.setdefault(t.source, len(self.sources)))
        key = _key(t.options)
        self.option.append(self.options.setdefault(key, (len(self.options), dict(t.options)))[0])
        self.points.extend(math.nan if v is None else v for v in (*t.p1, *t.p2))
        self.kind.append(NO_KIND if t.kind is None else KINDS.index(t.kind))
        if t.points is not None or t.on is not None:
            self.shapes.append((n, t.points, t.on))
        frame = NO_FRAME if t.frame is None else t.frame
        if isinstance(frame, str) and isinstance(self.frames, array):  # a history uid: frames become objects
            self.frames = list(self.frames)
        self.frames.append(frame)
        if t.error:
            self.errors.append((n, t.error, t.error_field))
        for k, v in t.extra.items():
            self.extra.setdefault(k, [None] * n)
        for k, values in self.extra.items():
            values.append(t.extra.get(k))

    def table(self) -> TaskTable:
        n = len(self.index)
        error = np.full(n, None, dtype=object)
        error_field = np.full(n, None, dtype=object)
        for row, message, fields in self.errors:
            error[row], error_field[row] = message, fields
        extra = {}
        for k, values in self.extra.items():
            extra[k] = np.empty(n, dtype=object)
            extra[k][:] = values
        frames = np.frombuffer(self.frames, dtype=np.int64) if isinstance(self.frames, array) else np.array(self.frames, dtype=object)
        clicks = on = None
        if self.shapes:
            clicks, on = np.full(n, None, dtype=object), np.full(n, None, dtype=object)
            for row, points, base in self.shapes:
                clicks[row], on[row] = points, base
        return TaskTable(
            np.frombuffer(self.index, dtype=np.int64),  # views of the builder's arrays, no copy
            np.frombuffer(self.source, dtype=np.int32),
            tuple(self.sources),
            frames,
            np.frombuffer(self.points, dtype=np.float64).reshape(n, 4),
            np.frombuffer(self.option, dtype=np.int32),
            tuple(opts for _, opts in self.options.values()),
            error,
            error_field,
            extra,
            np.frombuffer(self.kind, dtype=np.int8),
            clicks,
            on,
        )


@dataclass(frozen=True, eq=False)
class TaskTable(Sequence[Task]):
    """Tasks as columns (module docstring); ``table[i]`` is the i-th :class:`Task`, a slice or an
    index array is a table of those rows. ``frame`` is int64 (:data:`NO_FRAME` for none) or, for
    the service history, objects; ``points`` is (n, 4) float64 p1_x, p1_y, p2_x, p2_y, NaN for none;
    ``extra`` holds the carried-through columns, None where a row lacks one; ``kind`` indexes
    :data:`batch.tasks.KINDS` (:data:`NO_KIND` for none); ``clicks`` and ``on`` hold a shape's
    clicks (None for a segment), or are None when no task is a shape."""

    ids: np.ndarray  # each task's row in its table (Task.index)
    source: np.ndarray
    sources: tuple[str, ...]
    frame: np.ndarray
    points: np.ndarray
    option: np.ndarray
    options: tuple[dict[str, Any], ...]
    error: np.ndarray
    error_field: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    kind: np.ndarray | None = None  # None: every task is a segment
    clicks: np.ndarray | None = None
    on: np.ndarray | None = None

    @staticmethod
    def of(tasks: Iterable[Task]) -> TaskTable:
        cols = TaskColumns()
        for t in tasks:
            cols.add(t)
        return cols.table()

    def __len__(self) -> int:
        return len(self.ids)

    def __getitem__(self, item):  # type: ignore[no-untyped-def, override]
        if isinstance(item, (slice, np.ndarray, list)):
            return self.take(item)
        return self._task(int(item))

    def take(self, rows) -> TaskTable:  # noqa: ANN001 — a slice, index array or boolean mask
        return TaskTable(
            self.ids[rows], self.source[rows], self.sources, self.frame[rows], self.points[rows], self.option[rows],
            self.options, self.error[rows], self.error_field[rows], {k: v[rows] for k, v in self.extra.items()},
            *(None if a is None else a[rows] for a in (self.kind, self.clicks, self.on)),
        )  # fmt: skip

    def __iter__(self) -> Iterator[Task]:
        for i in range(len(self)):
            yield self._task(i)

    def _task(self, i: int) -> Task:
        p = [None if math.isnan(v) else v for v in self.points[i].tolist()]
        frame = self.frame[i]
        frame = None if frame is None or (not isinstance(frame, str) and frame == NO_FRAME) else (frame if isinstance(frame, str) else int(frame))
        extra = {k: v[i] for k, v in self.extra.items() if v[i] is not None}
        code = 0 if self.kind is None else int(self.kind[i])
        return Task(
            int(self.ids[i]), self.sources[self.source[i]], frame, (p[0], p[1]), (p[2], p[3]),
            dict(self.options[self.option[i]]), extra, self.error[i], self.error_field[i],
            None if code == NO_KIND else KINDS[code],
            None if self.clicks is None else self.clicks[i], None if self.on is None else self.on[i],
        )  # fmt: skip

    def invalid(self) -> np.ndarray:
        """A boolean mask of the invalid tasks."""
        return np.not_equal(self.error, None)


@dataclass(frozen=True)
class TaskGroup:
    """Tasks of one source, in frame order, for one worker call; ``defaults`` are the run's options.
    The invalid tasks of a run come in groups of their own, with ``source`` empty."""

    source: str
    tasks: Sequence[Task]  # a TaskTable slice from group_tasks; any sequence of tasks
    defaults: dict[str, Any] = field(default_factory=dict)
    run: str = ""
    schema: Any = None  # the run's pyarrow result schema (batch.schema); None: built from these tasks


def group_tasks(
    tasks: TaskTable | Sequence[Task], workers: int, defaults: dict[str, Any], run: str = "", max_group: int = 256, schema: Any = None
) -> list[TaskGroup]:
    """Tasks grouped by source, each group sorted by frame so every frame is read once.

    A random-access source (a recording, the history) is cut further, at frame boundaries, into
    groups of at most ``max_group`` tasks and at least enough groups to keep ``workers`` busy four
    times over: results then stream to disk as groups finish, and the load balances. A source read
    in order (a depth-PNG folder, a video) stays one group, or frames would be decoded twice.
    Invalid tasks make groups of at most ``max_group`` that open no source. Steps: sort the rows
    by (source, frame, row) on the columns; cut each source's run where a chunk has reached the
    target size and the frame changes.
    """
    table = tasks if isinstance(tasks, TaskTable) else TaskTable.of(tasks)
    bad = table.invalid()
    invalid = np.flatnonzero(bad)
    target = max(1, min(max_group, math.ceil(len(table) / max(1, 4 * workers))))
    groups = [TaskGroup("", table.take(invalid[i : i + max_group]), defaults, run, schema) for i in range(0, len(invalid), max_group)]
    valid = np.flatnonzero(~bad)
    if table.frame.dtype == object:  # history uids: sort by text (few rows: a service's history)
        frame_rank = np.unique(table.frame[valid].astype(str), return_inverse=True)[1]
    else:
        frame_rank = table.frame[valid]
    order = valid[np.lexsort((table.ids[valid], frame_rank, table.source[valid]))]
    frames = table.frame[order].astype(str) if table.frame.dtype == object else table.frame[order]
    codes = table.source[order]
    starts = np.flatnonzero(np.r_[True, codes[1:] != codes[:-1]]) if len(order) else np.array([], dtype=int)
    for a, b in zip(starts.tolist(), [*starts[1:].tolist(), len(order)]):
        source = table.sources[codes[a]]
        if source_kind(source) not in RANDOM_ACCESS_KINDS:
            groups.append(TaskGroup(source, table.take(order[a:b]), defaults, run, schema))
            continue
        # frame runs of this source: a chunk is cut at the first run boundary once it holds `target` tasks
        bounds = [a, *(a + 1 + np.flatnonzero(frames[a + 1 : b] != frames[a : b - 1])).tolist(), b]
        start = a
        for edge in bounds[1:]:
            if edge - start >= target or edge == b:
                groups.append(TaskGroup(source, table.take(order[start:edge]), defaults, run, schema))
                start = edge
    # The biggest first: a long group started last would leave the other workers idle at the end.
    groups.sort(key=lambda g: len(g.tasks), reverse=True)
    return groups
