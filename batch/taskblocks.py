"""Tasks as Arrow rows: the form in which Ray Data carries them from the table's reader, through the
sort that groups them, to the measuring workers.

A block has three columns: ``task`` (the row index), ``key`` (:func:`sort_key`: which recording
and frame the task reads, so that sorting on it puts a frame's tasks together and a recording's
frames in order) and ``payload`` (the pickled :class:`batch.tasks.Task`: the workers measure the
very task the table's row was parsed into, as the local executors do). :func:`boundaries` cuts the
sorted keys into partitions of about equal size that never split a key, so a partition holds whole
frames (and a source read in order, whole).
"""

from __future__ import annotations

import pickle
import zlib
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from batch.tasks import RANDOM_ACCESS_KINDS, Task, source_kind

FRAME_BITS = 32  # the low bits of a key: the frame within its source
BLOCK_TASKS = 4096  # tasks per block as the table's reader yields them


def sort_key(source: str, frame: int | str | None) -> int:
    """The grouping key of a task on ``frame`` of ``source`` (int64, >= 0): a digest of the source in
    the high bits and the frame in the low :data:`FRAME_BITS` (frame + 1, capped; a saved frame's
    file by its digest). A source read in order (a depth-PNG folder, a video) has one key for all its
    tasks, so one worker reads it, once, in order; a task without its frame has frame part 0. Two
    sources with the same digest share keys: their tasks then sort together, which costs nothing but
    balance (the workers group by the source itself)."""
    high = zlib.crc32(source.encode()) & 0x7FFFFFFF
    if frame is None or not source or source_kind(source) not in RANDOM_ACCESS_KINDS:
        low = 0
    elif isinstance(frame, str):
        low = zlib.crc32(frame.encode())
    else:
        low = min(int(frame) + 1, (1 << FRAME_BITS) - 1)
    return (high << FRAME_BITS) | low


def to_block(tasks: Iterable[Task]):  # noqa: ANN201 — a pyarrow Table
    """``tasks`` as one Arrow block (module docstring)."""
    import pyarrow as pa

    tasks = list(tasks)
    return pa.table({
        "task": pa.array([t.index for t in tasks], pa.int64()),
        "key": pa.array([sort_key(t.source, t.frame) for t in tasks], pa.int64()),
        "payload": pa.array([pickle.dumps(t, protocol=pickle.HIGHEST_PROTOCOL) for t in tasks], pa.binary()),
    })  # fmt: skip


def from_block(block: Any) -> list[Task]:
    """The tasks of a block made by :func:`to_block` (a pyarrow Table), in its row order."""
    return [pickle.loads(b) for b in block.column("payload").to_pylist()]


def measuring_order(tasks: Sequence[Task]) -> list[Task]:
    """``tasks`` as a worker measures them: invalid ones first, then by source, frame and row (a
    frame's tasks consecutive, so it is read once)."""

    def order(t: Task) -> tuple:
        frame = t.frame if isinstance(t.frame, int) else -1
        return (t.error is None, t.source, frame, t.frame if isinstance(t.frame, str) else "", t.index)

    return sorted(tasks, key=order)


def boundaries(keys: np.ndarray, parts: int) -> list[int]:
    """Sort boundaries that cut ``keys`` into at most ``parts`` partitions of about equal size:
    partition i holds the keys in [b[i-1], b[i]). Each boundary is a key itself, so the tasks of one
    key are never split between partitions."""
    keys = np.sort(np.asarray(keys, dtype=np.int64))
    if parts <= 1 or len(keys) == 0:
        return []
    cuts = np.unique(keys[(np.arange(1, parts) * len(keys)) // parts])
    return [int(b) for b in cuts[cuts > keys[0]]]


def partitions(tasks: int, workers: int, per_partition: int = 256, most: int = 256) -> int:
    """How many partitions a run of ``tasks`` tasks is cut into: about ``per_partition`` tasks each,
    at least 4 per worker (so the load balances), at most ``most`` (a sort moves partitions x input
    blocks pieces)."""
    return max(1, min(most, max(4 * workers, -(-tasks // per_partition))))
