"""Per test the CPU seconds it cost, beside pytest's wall-clock ``--durations``: the plugin that
``tests/conftest.py`` registers and ``tests/durations.py`` reads (docs/testing.md, "Where the time goes").

A test's CPU time is that of its setup, call and teardown: user + system seconds of the pytest process
(all its threads) and of the child processes it waited for in that time (a ``depthruler serve`` or
``record`` that a test started and stopped; a process still running, such as a Ray worker or a browser
kept for the module, is not counted). Measured in the process that runs the test and carried on its
report, so a run with pytest-xdist lists its workers' tests as well.

With ``--durations`` given, the run ends with one line per test, ``1.23s cpu <node id>`` (slowest
first, all of them with ``--durations=0``), the seconds the session spent before its first test
building the measuring kernels (tests/session_start.py; in no test's time), and a line with the
run's wall and CPU seconds and the host's 1-minute load average sampled every few seconds (the
machine is shared: a wall time means little without it), and whether Python writes its compiled files (not under PYTHONDONTWRITEBYTECODE:
then each process rewrites the test modules and compiles the project again unless an earlier run
wrote them, docs/testing.md).
"""

from __future__ import annotations

import os
import resource
import sys
import threading
import time
from collections import Counter

import pytest

LOAD_EVERY_S = 5.0
_START = pytest.StashKey[float]()


def cpu_seconds() -> float:
    """User + system CPU seconds of this process (all threads) and of its waited-for children."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


class LoadSampler:
    """The host's 1-minute load average, sampled every ``LOAD_EVERY_S`` seconds on a daemon thread."""

    def __init__(self) -> None:
        self.samples = [os.getloadavg()[0]]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="load-sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(LOAD_EVERY_S):
            self.samples.append(os.getloadavg()[0])

    def stop(self) -> list[float]:
        self._stop.set()
        self.samples.append(os.getloadavg()[0])
        return self.samples


class CpuTimes:
    """The plugin: times each phase of each test in the process that runs it, adds the seconds to
    the phase's report (``report.cpu_s``, which pytest-xdist carries to the controller) and sums them
    per node id where the reports arrive."""

    def __init__(self) -> None:
        self.per_test: Counter = Counter()
        self.wall0 = time.perf_counter()
        self.cpu0 = cpu_seconds()
        self.load = LoadSampler()
        # (wall, CPU) seconds of tests/session_start.py before the first test, set by tests/conftest.py
        self.session_start: tuple[float, float] | None = None

    def _timed(self, item: pytest.Item):
        item.stash[_START] = cpu_seconds()
        yield

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(self, item: pytest.Item):
        yield from self._timed(item)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item: pytest.Item):
        yield from self._timed(item)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(self, item: pytest.Item):
        yield from self._timed(item)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_makereport(self, item: pytest.Item, call: pytest.CallInfo):
        outcome = yield
        start = item.stash.get(_START, None)
        if start is not None:
            outcome.get_result().cpu_s = cpu_seconds() - start

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.per_test[report.nodeid] += getattr(report, "cpu_s", 0.0)

    def pytest_terminal_summary(self, terminalreporter, config: pytest.Config) -> None:
        samples = self.load.stop()
        count = config.getoption("durations", None)
        if count is None or not self.per_test:
            return
        rows = self.per_test.most_common(count or None)
        terminalreporter.write_sep("=", f"cpu seconds per test ({'all' if not count else f'slowest {count}'})")
        for node, seconds in rows:
            terminalreporter.write_line(f"{seconds:.2f}s cpu {node}")
        if self.session_start is not None:
            terminalreporter.write_line(f"session start: {self.session_start[0]:.1f}s wall, {self.session_start[1]:.1f}s cpu "
                                        "building the measuring kernels (or loading them from the caches), in no test")
        # This process's CPU since configure includes the workers only once they have exited; the
        # per-test sum is the figure that holds with and without xdist.
        terminalreporter.write_line(
            f"run: {time.perf_counter() - self.wall0:.1f}s wall, {sum(self.per_test.values()):.1f}s cpu in tests, "
            f"{cpu_seconds() - self.cpu0:.1f}s cpu in this process and its ended children, "
            f"load {min(samples):.1f}-{max(samples):.1f} (1-minute average, {len(samples)} samples, "
            f"start {samples[0]:.1f}, end {samples[-1]:.1f}); "
            f"compiled files {'not written (PYTHONDONTWRITEBYTECODE)' if sys.dont_write_bytecode else 'written'}")
