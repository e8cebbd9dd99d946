"""Batch re-measurement on Ray Data: the table read, grouped, measured and written by the workers;
the driver holds references, counts and the commit.

:func:`run_on_ray` in steps (how it was chosen: docs/decisions/batch-ray-data.md):

1. open the results store (the driver recovers what a killed run's commit left, as on any executor);
2. a Ray task lists the tasks earlier runs measured (:func:`batch.results.done_tasks`) and another
   scans the table once (:func:`batch.scan.scan_table`): rows, the result schema, done rows that
   changed (refused), sort boundaries. A table given as tasks (the service history) is scanned here;
3. Ray Data reads the table (:class:`TaskTableSource`: read tasks parse the rows with
   :func:`batch.tasks.parse_row` and skip the done ones) and sorts the tasks on their recording and
   frame (:func:`batch.taskblocks.sort_key`) into partitions of whole frames, kept in the object
   store (the driver holds their references) before any measuring worker starts, so the workers'
   reserved CPUs never starve the sort;
4. ``map_batches`` with :func:`measure_block`, a Ray task per partition in Ray's pooled worker
   processes (kept, with their imports, from one run to the next; each keeps the recordings it
   opened open, :mod:`batch.readers`), measures each partition with :func:`batch.rows.measure_group`,
   the local executors' per-group function, into rows of the run's one schema;
5. ``write_datasink`` with :class:`PartsSink`: each worker writes its blocks of rows as parts beside
   the results file (under a temporary name, fsync'd, renamed; named by their first task, so a
   write Ray retries replaces its own part); a progress actor counts rows for the driver's bar;
6. the driver commits the parts (:meth:`batch.results.ResultStore.finish`: the merge, which reads
   every row, in a Ray task; the renames that commit it here) and checks that every task has its
   row (a part written where the driver cannot see it is a missing row).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import ray
from ray.data import DataContext, Datasink, Datasource, ReadTask
from ray.data.block import BlockAccessor, BlockMetadata

from batch.errors import BatchError
from batch.readers import close_readers
from batch.results import ResultsError, ResultStore, done_tasks, merge_file, write_part
from batch.rows import GroupResult, extras, measure_group, project_version
from batch.scan import Plan, is_done, scan_table
from batch.schema import extra_types, parquet_bytes, result_schema, rows_table
from batch.taskblocks import BLOCK_TASKS, boundaries, from_block, measuring_order, partitions, sort_key, to_block
from batch.tasks import TaskError, parse_row
from batch.tasktable import TaskGroup, TaskTable

POLL_S = 0.5  # how often the driver reads the progress actor
TASK_BYTES = 200  # about the bytes of a task's row in a block (batch.taskblocks.to_block; mostly its pickle)


class TaskTableSource(Datasource):
    """A task table (a local path every node sees, or a URL) read by Ray Data: each read task parses
    its rows into tasks (:func:`batch.tasks.parse_row`, row indices as the table numbers them), skips
    those ``done`` (a reference to the sorted done task ids) and yields blocks of
    :data:`batch.taskblocks.BLOCK_TASKS` tasks. A local Parquet table is read by several tasks, a
    range of row groups each; a CSV or JSONL table (whose rows cannot be found without reading the
    ones before them) or a table at a URL by one."""

    def __init__(self, location: str, base: Path | str, done: Any, tasks: int) -> None:
        super().__init__()
        self.location, self.base, self.done, self.tasks = location, base, done, tasks

    def estimate_inmemory_data_size(self) -> int | None:
        # From the scan's count: Ray Data then cuts the read into blocks of about its target size
        # (at least 2 per CPU), not into 200 blocks of a few tasks each.
        return self.tasks * TASK_BYTES

    def get_name(self) -> str:
        return "TaskTable"

    def get_read_tasks(self, parallelism: int, per_task_row_limit: int | None = None, data_context: Any = None) -> list[ReadTask]:
        from batch.remote import is_url

        ranges: list[tuple[list[int] | None, int]] = [(None, 0)]
        if not is_url(self.location) and Path(self.location).suffix.lower() in (".parquet", ".pq"):
            import pyarrow.parquet as pq

            with contextlib.suppress(OSError, ValueError):  # an unreadable file: one task, whose reader says why
                meta = pq.ParquetFile(self.location).metadata
                sizes = [meta.row_group(g).num_rows for g in range(meta.num_row_groups)]
                offsets = np.r_[0, np.cumsum(sizes)].astype(int).tolist()
                per = max(1, -(-len(sizes) // max(1, parallelism)))
                ranges = [(list(range(g, min(g + per, len(sizes)))), offsets[g]) for g in range(0, len(sizes), per)] or ranges
        meta = BlockMetadata(num_rows=None, size_bytes=None, input_files=None, exec_stats=None)
        return [ReadTask(lambda groups=groups, first=first: self._read(groups, first), meta, per_task_row_limit=per_task_row_limit)
                for groups, first in ranges]  # fmt: skip

    def _read(self, row_groups: list[int] | None, first: int):  # noqa: ANN202 — blocks
        from batch.scan import table_rows
        from batch.tasks import read_rows

        done = ray.get(self.done) if self.done is not None else np.zeros(0, np.int64)
        rows = table_rows(self.location) if row_groups is None else read_rows(Path(self.location), row_groups)
        tasks = []
        for i, row in enumerate(rows, first):
            if len(done) and is_done(done, i) >= 0:
                continue
            tasks.append(parse_row(i, row, self.base))
            if len(tasks) >= BLOCK_TASKS:
                yield to_block(tasks)
                tasks = []
        if tasks:
            yield to_block(tasks)


_measured_run = [""]  # the run whose tasks this worker process measured last


def measure_block(block: Any, defaults: dict[str, Any], run: str, schema: Any) -> Any:
    """The measuring function of ``map_batches``, a Ray task per partition: its tasks (a block made by
    :func:`batch.taskblocks.to_block`) measured by :func:`batch.rows.measure_group` for each run of one
    source (a frame's tasks together) into a block of result rows in the run's schema. Ray runs it in
    its pooled worker processes, kept from one partition and one run to the next with their imports;
    a worker keeps the recordings it opened open across partitions (:mod:`batch.readers`) and closes
    them when a new run starts, so a run sees the archive as it is then."""
    if _measured_run[0] != run:
        close_readers()
        _measured_run[0] = run
    rows: list[dict[str, Any]] = []
    ordered = measuring_order(from_block(block))
    for source, same in itertools.groupby(ordered, key=lambda t: "" if t.error else t.source):
        rows += measure_group(TaskGroup(source, list(same), defaults, run, schema))
    return rows_table(rows, schema)


@ray.remote(num_cpus=0)
class Progress:
    """Rows and error rows each run has written so far, told by the writers, read by the driver's
    progress bar. One per driver and Ray session (:func:`progress_actor`): made for every run, its
    process start and imports cost about as much CPU as measuring 60 tasks."""

    def __init__(self) -> None:
        self.counts: dict[str, list[int]] = {}

    def add(self, run: str, rows: int, errors: int) -> None:
        counts = self.counts.setdefault(run, [0, 0])
        counts[0] += rows
        counts[1] += errors

    def get(self, run: str) -> tuple[int, int]:
        rows, errors = self.counts.get(run, (0, 0))
        return rows, errors

    def forget(self, run: str) -> None:
        self.counts.pop(run, None)


_progress: dict[tuple[str, str], Any] = {}  # the actor's handle by Ray session (job and node ids)


def progress_actor() -> Any:
    """This driver's :class:`Progress` actor, made on its first run in a Ray session and kept (its
    handle held here: Ray ends an actor when its maker's handle goes) until the driver ends or Ray is
    shut down; on this driver's node, not on one that may be lost."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    context = ray.get_runtime_context()
    session = (context.get_job_id(), context.get_node_id())
    if session not in _progress:
        _progress.clear()
        _progress[session] = Progress.options(scheduling_strategy=NodeAffinitySchedulingStrategy(session[1], soft=True)).remote()
    return _progress[session]


class PartsSink(Datasink):
    """Ray Data's writer of result parts: a write task stores the rows it is given as one part in
    ``folder`` (:func:`batch.results.write_part`), named by its first task, and tells ``progress``."""

    def __init__(self, folder: str, progress: Any, run: str) -> None:
        self.folder, self.progress, self.run = folder, progress, run

    def get_name(self) -> str:
        return "ResultParts"

    def write(self, blocks: Any, ctx: Any) -> tuple[int, int]:
        import pyarrow as pa
        import pyarrow.compute as pc

        tables = [BlockAccessor.for_block(b).to_arrow() for b in blocks]
        table = pa.concat_tables([t for t in tables if t.num_rows]) if any(t.num_rows for t in tables) else None
        if table is None:
            return 0, 0
        first = pc.min(table.column("task")).as_py()
        write_part(Path(self.folder) / f"part-t{first:012d}.parquet", parquet_bytes(table))
        errors = table.num_rows - table.column("error").null_count
        self.progress.add.remote(self.run, table.num_rows, errors)
        return table.num_rows, errors


def _remote_merge(tmp: Path, sources: list[Path], metadata: dict[str, str] | None) -> int:
    """:func:`batch.results.merge_file` in a Ray task (the merge reads every row: not in the driver);
    its exceptions as raised."""
    try:
        return ray.get(ray.remote(merge_file).options(num_cpus=0, max_retries=0).remote(tmp, sources, metadata))
    except ray.exceptions.RayTaskError as exc:
        raise _cause(exc) from None


def _sorted_ids(done: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    return np.sort(done[0])


def _quiet() -> None:
    """Ray Data's own progress bars and execution logs off: the command shows its own bar."""
    ctx = DataContext.get_current()
    ctx.enable_progress_bars = False
    for name in ("enable_operator_progress_bars", "print_on_execution_start"):
        if hasattr(ctx, name):
            setattr(ctx, name, False)
    logging.getLogger("ray.data").setLevel(logging.ERROR)  # its warnings are about the progress bars turned off here


def _cause(exc: BaseException) -> BaseException:
    """The exception a Ray task raised, out of Ray's wrappers."""
    while isinstance(getattr(exc, "cause", None), BaseException):
        exc = exc.cause  # type: ignore[attr-defined]
    return exc


def _plan_of(table: TaskTable, done: tuple[np.ndarray, np.ndarray], defaults: dict[str, Any], workers: int) -> tuple[Plan, TaskTable]:
    """The :class:`batch.scan.Plan` of tasks given in memory (the service history), and those to do."""
    order = np.argsort(done[0], kind="stable")
    ids, keys = done[0][order], done[1][order]
    at = np.array([is_done(ids, int(i)) if len(ids) else -1 for i in table.ids], dtype=np.int64)
    changed = [int(table.ids[i]) for i in np.flatnonzero(at >= 0) if keys[at[i]] != table[int(i)].key(defaults)]
    todo = table.take(at < 0)
    sort_keys = np.array([sort_key(t.source, t.frame) for t in todo], dtype=np.int64)
    plan = Plan(len(table), len(todo), extra_types(extras(table)), boundaries(sort_keys, partitions(len(todo), workers)),
                (changed[0], len(changed)) if changed else None)  # fmt: skip
    return plan, todo


def run_on_ray(
    tasks: TaskTable | str,
    out: Path,
    executor: Any,
    *,
    defaults: dict[str, Any],
    base: Path | str | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_start: Callable[[int, int], None] | None = None,
    on_group: Callable[[GroupResult], None] | None = None,
) -> dict[str, Any]:
    """Measure ``tasks`` (a table's location, read by the workers, with ``base`` the folder its
    relative sources are in; or tasks in memory) on the Ray cluster of ``executor`` (a
    :class:`batch.executors.RayExecutor`) into ``out``; the summary of :func:`batch.run.run_batch`.
    Steps in the module docstring."""
    from batch.run import error_counts, run_counts

    _quiet()
    store = ResultStore(out, resume=resume, overwrite=overwrite)
    workers = executor.workers
    if isinstance(tasks, TaskTable):
        plan, todo = _plan_of(tasks, store.done(), defaults, workers)
        dataset = ray.data.from_arrow([to_block(todo[i : i + BLOCK_TASKS]) for i in range(0, len(todo), BLOCK_TASKS)] or [to_block([])])
    else:
        done = ray.remote(done_tasks).options(num_cpus=0).remote(out)
        try:
            plan = ray.get(ray.remote(scan_table).remote(tasks, base, done, defaults, workers))
        except ray.exceptions.RayTaskError as exc:
            cause = _cause(exc)
            raise (cause if isinstance(cause, BatchError) else TaskError(f"{tasks} cannot be read: {cause}")) from None
        done_ids = ray.remote(_sorted_ids).options(num_cpus=0).remote(done)
        dataset = ray.data.read_datasource(TaskTableSource(tasks, base, done_ids, plan.todo))
    if plan.changed:
        first, count = plan.changed
        raise ResultsError(
            f"{count} task(s) (first: row {first + 1}) differ from the ones {out} holds for those rows; "
            "the task table or the --set options changed since that run: use --overwrite"
        )
    run = uuid.uuid4().hex[:12]
    schema = result_schema(plan.extra_types)
    if on_start:
        on_start(plan.todo, plan.rows - plan.todo)
    t0 = time.perf_counter()
    if plan.todo:
        _measure(dataset, plan, store, executor, defaults, run, schema, on_group)
    wall = time.perf_counter() - t0
    total = store.finish(
        {"depthruler.version": project_version(), "depthruler.defaults": json.dumps(defaults),
         "depthruler.executor": executor.describe() + " with Ray Data"}, merge=_remote_merge,
    )  # fmt: skip
    if total < plan.rows:
        raise ResultsError(
            f"{out} holds {total} rows for {plan.rows} tasks: the workers wrote parts where this machine does not see them; "
            "put --out on storage every Ray node sees (a shared filesystem), then run again with --resume"
        )
    measured, error_rows = run_counts(out, run)
    return {"run": run, "measured": measured, "error_rows": error_rows, "skipped": plan.rows - plan.todo, "rows": total,
            "groups": len(plan.boundaries) + 1, "wall_s": wall, "errors": error_counts(out)}  # fmt: skip


def _measure(dataset: Any, plan: Plan, store: ResultStore, executor: Any, defaults: dict[str, Any], run: str, schema: Any,
             on_group: Callable[[GroupResult], None] | None) -> None:  # fmt: skip
    """Steps 3-5 of the module docstring (``on_group`` told of the rows written as the workers write them)."""
    # Grouped in an execution of its own: in one with the measuring, Ray Data fuses the measuring into
    # the sort's reduce tasks or gives it a share of the CPUs, and one worker measures nearly every
    # partition. One partition when every task has the same key (one frame, or one source read in order).
    grouped = (dataset.sort("key", boundaries=plan.boundaries) if plan.boundaries else dataset.repartition(1)).materialize()
    progress = progress_actor()
    stop = threading.Event()
    seen = [0, 0]

    def poll() -> None:
        while True:
            finished = stop.wait(POLL_S)
            rows, errors = ray.get(progress.get.remote(run))
            if on_group and rows > seen[0]:
                on_group(GroupResult(rows - seen[0], errors - seen[1], b""))
            seen[:] = [rows, errors]
            if finished:
                return

    watcher = threading.Thread(target=poll, name="batch-progress", daemon=True)
    watcher.start()
    try:
        grouped.map_batches(
            measure_block, fn_kwargs={"defaults": defaults, "run": run, "schema": schema}, batch_size=None,
            batch_format="pyarrow", num_cpus=executor.task_cpus,
        ).write_datasink(PartsSink(str(store.parts), progress, run), ray_remote_args={"num_cpus": executor.task_cpus})  # fmt: skip
    except Exception as exc:
        cause = _cause(exc)
        if isinstance(cause, OSError):
            raise ResultsError(
                f"cannot write a result part in {store.parts} ({cause.strerror or cause}); the parts written are kept: "
                "free space or fix the folder, then run again with --resume"
            ) from None
        raise
    finally:
        stop.set()
        watcher.join()
        progress.forget.remote(run)
