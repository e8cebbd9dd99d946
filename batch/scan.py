"""What a run on Ray Data must know before it starts, from one pass over the task table by a worker.

:func:`scan_table` reads the table's rows (not parsing them into tasks, except those an earlier run
already measured) and gives a :class:`Plan`: how many rows there are and how many are still to do,
the types of the carried-through columns (the run's one result schema, typed as on every executor
by :class:`batch.schema.ExtraTypes`), the done rows whose task is no longer the same (the run is
then refused, as on every executor), and the sort boundaries that cut the rows to do into
partitions of whole frames (:func:`batch.taskblocks.boundaries`). A table that cannot be a task
table (no row, a required column missing) is refused with the same TaskError as
:func:`batch.tasks.read_tasks` gives.
"""

from __future__ import annotations

import tempfile
from array import array
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from batch.rows import flatten
from batch.schema import ExtraTypes
from batch.taskblocks import boundaries, partitions, sort_key
from batch.tasks import BadLine, check_table, parse_row, read_rows, row_extra, task_place


@dataclass(frozen=True)
class Plan:
    """A run's plan (module docstring). ``changed``: the first changed row and how many there are."""

    rows: int
    todo: int
    extra_types: dict[str, Any]
    boundaries: list[int]
    changed: tuple[int, int] | None = None


def table_rows(location: str) -> Iterator[dict[str, Any] | BadLine]:
    """The rows of the task table at ``location`` (a local path or a URL, fetched into a temporary folder)."""
    from batch.remote import fetch_table, is_url

    if is_url(location):
        with tempfile.TemporaryDirectory() as folder:
            yield from read_rows(fetch_table(location, Path(folder)))
    else:
        yield from read_rows(Path(location))


def is_done(done_ids: np.ndarray, i: int) -> int:
    """The position of row ``i`` in the sorted ``done_ids``, or -1."""
    at = int(np.searchsorted(done_ids, i))
    return at if at < len(done_ids) and done_ids[at] == i else -1


def scan_rows(
    rows: Iterable[dict[str, Any] | BadLine], base: Path | str, where: str, done: tuple[np.ndarray, np.ndarray],
    defaults: dict[str, Any], workers: int,
) -> Plan:  # fmt: skip
    """The :class:`Plan` of ``rows`` (a table's, in order; relative sources resolved against ``base``)
    given the ``done`` (task ids, task keys) of earlier runs and the run's ``defaults``."""
    order = np.argsort(done[0], kind="stable")
    done_ids, done_keys = done[0][order], done[1][order]
    types = ExtraTypes()
    keys = array("q")
    columns: set[str] = set()
    n, first_changed, changed = 0, -1, 0
    for i, row in enumerate(rows):
        n += 1
        if isinstance(row, dict):
            if not columns.issuperset(row):
                columns.update(k for k in row if k is not None)
            for k, v in row_extra(row).items():
                types.add(k, None if v is None else flatten(v))
        at = is_done(done_ids, i) if len(done_ids) else -1
        if at >= 0:
            if parse_row(i, row, base).key(defaults) != done_keys[at]:
                changed += 1
                first_changed = i if first_changed < 0 else first_changed
            continue
        keys.append(sort_key(*task_place(row, base)) if isinstance(row, dict) else sort_key("", None))
    check_table(columns, n, where)
    todo = np.frombuffer(keys, dtype=np.int64) if len(keys) else np.zeros(0, np.int64)
    return Plan(n, len(todo), types.types(), boundaries(todo, partitions(len(todo), workers)),
                (first_changed, changed) if changed else None)  # fmt: skip


def scan_table(location: str, base: Path | str, done: tuple[np.ndarray, np.ndarray], defaults: dict[str, Any], workers: int) -> Plan:
    """:func:`scan_rows` of the table at ``location`` (run in a Ray task, by a worker)."""
    return scan_rows(table_rows(location), base, location, done, defaults, workers)
