"""Where the evaluation and the batch runner do their work: this process, a local process pool or a
Ray cluster, behind one call, :meth:`Executor.imap` (a batch on Ray runs on Ray Data instead,
:mod:`batch.raydata`; the executor then only connects and counts the workers).

Each item handed to an executor is a *group* of work that belongs together (one recording's tasks,
one simulated view's jobs), so a worker opens a recording or renders a view once. ``imap`` yields
``(index, result)`` as each group finishes, in completion order, so a caller can stream results to
disk and a crash keeps what was done. ``fn`` must be a module-level function (it is pickled by name)
and should turn its own failures into results: an exception that escapes it ends the run.

Executors with workers keep at most :func:`window` groups in flight (submitted, not yet yielded)
and take the next item only when one finishes, so the driver's memory and the cost of each wait
stay the same whatever the number of groups, and ``items`` may be a lazy iterable.

Ray is optional (``pip install 'depthruler[ray]'``) and imported only when a Ray executor is made.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Protocol, TypeVar

from batch.errors import BatchError

T = TypeVar("T")
R = TypeVar("R")


def window(workers: int) -> int:
    """Groups in flight for ``workers`` workers: two each, so a worker never waits for the driver."""
    return 2 * max(1, workers)


IDLE_WORKER_MS = 10 * 60 * 1000  # how long a private Ray instance keeps an idle worker process


class ExecutorError(BatchError):
    """An executor cannot be made as asked (bad worker count, Ray missing or unreachable)."""


class Executor(Protocol):
    name: str
    workers: int

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[tuple[int, R]]: ...

    def close(self) -> None: ...

    def describe(self) -> str: ...


class InProcessExecutor:
    """Runs every group in this process, in order: no start-up cost, for small jobs and debugging."""

    name = "in-process"
    workers = 1

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[tuple[int, R]]:
        for i, item in enumerate(items):
            yield i, fn(item)

    def close(self) -> None:
        pass

    def describe(self) -> str:
        return "in this process"

    def __enter__(self) -> InProcessExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PoolExecutor:
    """A pool of ``workers`` local processes (spawned, not forked: the caller may run a progress-bar
    thread, and forked threads deadlock). The pool starts on first use and is reused until close()."""

    name = "pool"

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ExecutorError(f"--workers={workers} must be at least 1")
        self.workers = workers
        self._pool = None

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[tuple[int, R]]:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=mp.get_context("spawn"))
        from concurrent.futures import FIRST_COMPLETED, wait

        todo = enumerate(items)
        futures = {self._pool.submit(fn, item): i for i, item in itertools.islice(todo, window(self.workers))}
        try:
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for fut in done:
                    i = futures.pop(fut)
                    for j, item in itertools.islice(todo, 1):
                        futures[self._pool.submit(fn, item)] = j
                    yield i, fut.result()
        finally:
            for fut in futures:
                fut.cancel()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def describe(self) -> str:
        return f"on a pool of {self.workers} local processes"

    def __enter__(self) -> PoolExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RayExecutor:
    """A Ray cluster: the evaluation's groups as Ray tasks (:meth:`imap`), each reserving ``task_cpus``
    CPUs (default 1); a batch run on it goes through Ray Data instead (:mod:`batch.raydata`), with
    :attr:`workers` measuring actors of ``task_cpus`` CPUs each.

    ``address``: ``"local"`` starts a private Ray instance on this machine, never one already running (``num_cpus`` CPUs, default all);
    ``"auto"`` joins the cluster already running here or named by ``RAY_ADDRESS``; anything else is
    a cluster address (``HOST:6379`` or ``ray://HOST:10001``). When Ray is already initialised in
    this process (a test's ``ray.init(num_cpus=2)``, a notebook) that connection is used as it is.
    Every node needs depthruler installed at the same version and the inputs at the same paths.
    """

    name = "ray"

    def __init__(self, address: str = "auto", num_cpus: int | None = None, task_cpus: int = 1) -> None:
        if address != "local":
            _send_token_if_held()  # before the import: Ray reads its authentication mode when it loads
        try:
            import ray
        except ImportError as exc:
            raise ExecutorError("--ray needs Ray; install it with: pip install 'depthruler[ray]'") from exc
        self._ray = ray
        self._started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            # "local" must not join a Ray another program started here: address="local" always starts a private one.
            kwargs["address"] = address
            if address == "local":
                kwargs["num_cpus"] = num_cpus
                # Ray kills a worker idle for 1 s; the next group then waits for a new process and its
                # imports (~1.4 s of CPU). Measured: 2 workers gave 0.98x of 1 as workers were restarted
                # between batches, 1.66x with them kept. A private instance keeps them, as a pool does.
                kwargs["_system_config"] = {"idle_worker_killing_time_threshold_ms": IDLE_WORKER_MS}
            try:
                ray.init(**kwargs)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise ExecutorError(
                    f"cannot reach a Ray cluster at {address!r} ({exc}); start one with `ray start --head`, "
                    "give its address (HOST:6379 or ray://HOST:10001), or use --ray local; a cluster with token "
                    "authentication needs its token here too (~/.ray/auth_token or RAY_AUTH_TOKEN, see docs/batch.md)"
                ) from exc
            self._started = True
        self.task_cpus = task_cpus
        self.workers = max(1, int(ray.cluster_resources().get("CPU", 1)) // task_cpus)
        self._remote: dict[Callable, Any] = {}

    def imap(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[tuple[int, R]]:
        ray = self._ray
        remote = self._remote.get(fn)
        if remote is None:
            # Ray retries a group whose worker or node died (its rows reach the caller only once it finished).
            remote = self._remote[fn] = ray.remote(num_cpus=self.task_cpus)(fn)
        todo = enumerate(items)
        refs = {remote.remote(item): i for i, item in itertools.islice(todo, window(self.workers))}
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1)
                for ref in ready:
                    i = refs.pop(ref)
                    for j, item in itertools.islice(todo, 1):
                        refs[remote.remote(item)] = j
                    yield i, ray.get(ref)
        finally:
            for ref in refs:
                ray.cancel(ref)

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False

    def describe(self) -> str:
        nodes = sum(1 for n in self._ray.nodes() if n.get("Alive"))
        cpus = int(self._ray.cluster_resources().get("CPU", 1))
        return f"on Ray ({cpus} CPUs on {nodes} node(s), {self.workers} workers)"

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _send_token_if_held() -> None:
    """Join with token authentication when this machine holds a Ray token and nobody chose a mode.

    ``ray start --head`` turns token authentication on whenever ``~/.ray/auth_token`` exists, but a
    driver joining by address sends no token unless ``RAY_AUTH_MODE=token`` is set (it then fails with
    InvalidAuthToken); a cluster without authentication accepts a driver that sends one. Ray reads the
    mode once per process, when it is imported, so it is set before that."""
    if os.environ.get("RAY_AUTH_MODE"):
        return
    held = os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")
    if held or os.path.isfile(os.path.expanduser("~/.ray/auth_token")):
        os.environ["RAY_AUTH_MODE"] = "token"


def make_executor(workers: int | None = None, ray: str | None = None) -> InProcessExecutor | PoolExecutor | RayExecutor:
    """The executor the command line asks for: ``--ray ADDRESS`` -> Ray (``workers`` caps a local
    instance's CPUs); else ``--workers 1`` -> this process; ``--workers N`` -> a pool of N processes;
    no ``--workers`` -> a pool of one process per CPU."""
    if ray:
        return RayExecutor(ray, num_cpus=workers)
    n = workers if workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ExecutorError(f"--workers={n} must be at least 1")
    return InProcessExecutor() if n == 1 else PoolExecutor(n)
