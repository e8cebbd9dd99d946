"""What a test session does once, before its first test: the measuring kernels built ahead of time for
this machine (numba compiling them on the way), or loaded from the caches when an earlier run wrote
them (docs/testing.md, "Where the time goes"; docs/decisions/test-tail.md).

Called by ``tests/conftest.py`` at the session's start in the process that starts the session: with
pytest-xdist that is the controller, before its workers start, so the workers load what it wrote
instead of each compiling the same kernels at once; a Ray or process-pool worker a test starts loads
them too. Without it the first test that measures carried the compile (about 11 s of CPU from a fresh
checkout, when no cache is on disk). The seconds it took are printed beside the tests' own with
``--durations`` (tests/cpu_times.py) and given as their own line in docs/test-times.md.
"""

from __future__ import annotations

import resource
import time
from dataclasses import dataclass

import pytest


@dataclass(frozen=True)
class Warmed:
    """What the session start took: wall and CPU seconds."""

    wall_s: float
    cpu_s: float


WARMED = pytest.StashKey[Warmed]()  # on the config of the process that ran it


def _cpu_with_children() -> float:
    """CPU seconds of this process and of its children that ended (the build's subprocess)."""
    own, ended = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + ended.ru_utime + ended.ru_stime


def compile_measuring_kernels() -> Warmed:
    """``measure.warm_up()``, timed: the kernels built ahead of time for this machine (in a subprocess,
    whose CPU is counted) or loaded from the cache, every one with the array types a measurement passes
    it (tests/measure/test_warm_up.py holds it to that)."""
    wall0, cpu0 = time.perf_counter(), _cpu_with_children()
    from measure import warm_up

    warm_up()
    return Warmed(time.perf_counter() - wall0, _cpu_with_children() - cpu0)
