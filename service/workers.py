"""The measurement worker pool: as many measurements at once as the CPU has cores, a short queue,
then :class:`Busy` (HTTP 429 with ``Retry-After``).

A measurement holds the interpreter's lock for most of its few milliseconds; run on the server's
general thread pool (40 threads), 32 of them at once starved the event loop, and with it the live
view, the long-polls and health (docs/decisions/measure-pool.md). :class:`MeasurePool` runs them
on ``workers`` threads of their own, below the server's other threads in the CPU's queue, and
refuses a request when ``queue`` are already waiting.
"""

from __future__ import annotations

import asyncio
import functools
import os
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")


def lower_priority(nice: int) -> None:
    """Raise the calling thread's niceness by ``nice`` (Linux, where each thread has its own; elsewhere
    nothing): a thread only lowers its own priority, which needs no privilege."""
    if nice <= 0 or not sys.platform.startswith("linux"):
        return
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, min(os.getpriority(os.PRIO_PROCESS, tid) + nice, 19))
    except OSError:  # a sandbox without setpriority: the pool still works, at the server's priority
        pass


class Busy(RuntimeError):
    """Every measurement worker is busy and the queue is full (HTTP 429, ``Retry-After``)."""


class MeasurePool:
    """``workers`` threads (0: ``os.cpu_count()``), ``nice`` steps below the server's priority, and at
    most ``queue`` calls waiting for one."""

    def __init__(self, workers: int = 0, queue: int = 8, nice: int = 0) -> None:
        self.workers = workers or os.cpu_count() or 1
        self.queue = queue
        self._executor = ThreadPoolExecutor(self.workers, thread_name_prefix="measure",
                                            initializer=functools.partial(lower_priority, nice))
        self._lock = threading.Lock()
        self._inside = 0  # running + waiting

    @property
    def inside(self) -> int:
        """Measurements running or waiting now."""
        with self._lock:
            return self._inside

    async def run(self, fn: Callable[..., T], *args: object) -> T:
        """``fn(*args)`` on a worker thread, awaited; raises :class:`Busy` at once when the workers
        and the queue are full (nothing of ``fn`` ran)."""
        with self._lock:
            if self._inside >= self.workers + self.queue:
                raise Busy(
                    f"{self._inside} measurements are running or waiting (the server measures {self.workers} at once "
                    f"and queues {self.queue}); retry after a second"
                )
            self._inside += 1
        try:
            future = self._executor.submit(fn, *args)
        except RuntimeError:  # shut down
            self._done(None)
            raise
        future.add_done_callback(self._done)  # counted until it ends, even when its client is gone
        return await asyncio.wrap_future(future)

    def _done(self, _: object) -> None:
        with self._lock:
            self._inside -= 1

    def close(self) -> None:
        self._executor.shutdown(wait=True)
