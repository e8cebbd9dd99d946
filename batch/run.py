"""Batch re-measurement, the driver: tasks in, one committed result row per task out.

:func:`run_batch` in steps, in this process or on a local pool: open the results store
(:mod:`batch.results`; on ``--resume`` it recovers what a killed run left and lists the tasks
already done); check that those tasks are still the same ones; group the others
(:func:`batch.tasktable.group_tasks`) and run the groups on the executor, each group's Parquet rows
written as a part the moment it arrives; commit the parts and the earlier rows as one file sorted
by task; count the error rows by type. On Ray the same steps run on Ray Data, the table read and
the parts written by the workers (:mod:`batch.raydata`).
"""

from __future__ import annotations

import json
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from measure import MeasureError, MeasureOptions

from batch.readers import close_readers
from batch.rows import GroupResult, extras, project_version, run_group
from batch.schema import extra_types, result_schema
from batch.tasks import OPTION_FIELDS, TableFile, Task, TaskError, parse_option, read_tasks
from batch.tasktable import TaskGroup, TaskTable, group_tasks

__all__ = ["close_readers", "default_options", "error_counts", "run_batch", "run_tasks"]


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


def _batches(out: Path, columns: list[str]):  # noqa: ANN202 — record batches
    """The ``columns`` (those ``out`` has) of results file ``out``, batch by batch (bounded memory)."""
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(out)
    return pf.iter_batches(batch_size=65536, columns=[c for c in columns if c in pf.schema_arrow.names])


def error_counts(out: Path) -> dict[str, Counter]:
    """The error rows of results file ``out``: ``{"type": Counter(error_type), "field": Counter(error_field)}``
    (counted by Arrow batch by batch: a million error rows make no million Python strings)."""
    import pyarrow.compute as pc

    types: Counter = Counter()
    fields: Counter = Counter()
    for batch in _batches(out, ["error_type", "error_field"]):  # older files lack error_field
        for column, counter in (("error_type", types), ("error_field", fields)):
            if column in batch.schema.names:
                counter.update({v["values"]: v["counts"] for v in pc.value_counts(batch.column(column)).to_pylist() if v["values"] is not None})
    by_field: Counter = Counter()
    for text, k in fields.items():
        for f in text.split(","):
            by_field[f] += k
    return {"type": types, "field": by_field}


def run_counts(out: Path, run: str) -> tuple[int, int]:
    """(rows, error rows) that run ``run`` wrote to results file ``out``."""
    import pyarrow.compute as pc

    rows = errors = 0
    for batch in _batches(out, ["run", "error_type"]):
        mine = pc.equal(batch.column("run"), run)
        rows += int(pc.sum(mine).as_py() or 0)
        errors += int(pc.sum(pc.and_(mine, pc.is_valid(batch.column("error_type")))).as_py() or 0)
    return rows, errors


def run_batch(
    tasks: TaskTable | Sequence[Task] | TableFile,
    out: Path,
    executor: Any,
    *,
    defaults: dict[str, Any] | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[int, int], None] | None = None,
    on_group: Callable[[GroupResult], None] | None = None,
) -> dict[str, Any]:
    """Measure ``tasks`` on ``executor`` into the Parquet file ``out``; a summary dict (module docstring).
    A :class:`batch.tasks.TableFile` is read by Ray Data's workers on Ray, here otherwise.

    ``on_start(to_do, already_done)`` is called before the first group runs. With ``resume`` the
    tasks already in ``out`` or its parts are skipped (ResultsError if one of them is no longer the
    same task: the table changed since that run). The summary: ``run`` id, ``measured`` and
    ``error_rows`` (rows this run wrote, and how many are errors), ``skipped`` (kept from before),
    ``rows`` (in ``out``), ``groups``, ``wall_s`` (seconds) and ``errors`` (:func:`error_counts` of
    ``out``)."""
    from batch.executors import RayExecutor
    from batch.results import ResultsError, ResultStore

    defaults = dict(defaults or {})
    if isinstance(executor, RayExecutor):
        from batch.raydata import run_on_ray

        source = tasks if isinstance(tasks, (TaskTable, TableFile)) else TaskTable.of(tasks)
        return run_on_ray(source.location if isinstance(source, TableFile) else source, out, executor, defaults=defaults,
                          base=source.base if isinstance(source, TableFile) else None, resume=resume, overwrite=overwrite,
                          on_start=on_start, on_group=on_group)  # fmt: skip
    if isinstance(tasks, TableFile):
        tasks = read_tasks(tasks)
    table = tasks if isinstance(tasks, TaskTable) else TaskTable.of(tasks)
    store = ResultStore(out, resume=resume, overwrite=overwrite)
    done_ids, done_keys = store.done()
    order = np.argsort(done_ids, kind="stable")
    at = np.minimum(np.searchsorted(done_ids, table.ids, sorter=order), max(len(order) - 1, 0))
    is_done = done_ids[order[at]] == table.ids if len(order) else np.zeros(len(table), dtype=bool)
    changed = [int(table.ids[i]) for i in np.flatnonzero(is_done) if done_keys[order[at[i]]] != table[int(i)].key(defaults)]
    if changed:
        raise ResultsError(
            f"{len(changed)} task(s) (first: row {changed[0] + 1}) differ from the ones {out} holds for those rows; "
            "the task table or the --set options changed since that run: use --overwrite"
        )
    todo = table.take(~is_done) if is_done.any() else table  # no copy of a million rows on a fresh run
    run = uuid.uuid4().hex[:12]
    groups = group_tasks(todo, getattr(executor, "workers", 1), defaults, run, schema=result_schema(extra_types(extras(table))))
    skipped = len(table) - len(todo)
    if on_start:
        on_start(len(todo), skipped)
    t0 = time.perf_counter()
    try:
        n = run_tasks(executor, groups, store, on_group)
    finally:
        close_readers()  # the in-process executor's sources: a later run must see the archive as it is then
    wall = time.perf_counter() - t0
    total = store.finish(
        {"depthruler.version": project_version(), "depthruler.defaults": json.dumps(defaults), "depthruler.executor": executor.describe()}
    )
    return {
        "run": run, "measured": n, "error_rows": run_counts(out, run)[1], "skipped": skipped, "rows": total, "groups": len(groups),
        "wall_s": wall, "errors": error_counts(out),
    }  # fmt: skip
