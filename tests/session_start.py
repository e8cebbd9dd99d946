"""What a test session does once, before its first test: the measuring kernels compiled by numba, or
loaded from numba's disk cache when an earlier run wrote it (docs/testing.md, "Where the time goes";
docs/decisions/test-tail.md).

Called by ``tests/conftest.py`` at the session's start in the process that starts the session: with
pytest-xdist that is the controller, before its workers start, so the workers load what it wrote
instead of each compiling the same kernels at once; a Ray or process-pool worker a test starts loads
them too. Without it the first test that measures carried the compile (about 11 s of CPU from a fresh
checkout, when no cache is on disk). The seconds it took are printed beside the tests' own with
``--durations`` (tests/cpu_times.py) and given as their own line in docs/test-times.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import pytest

KERNEL_MODULES = ("measure.kernels", "measure.fit_kernels")


@dataclass(frozen=True)
class Warmed:
    """What the session start did: its wall and CPU seconds, and the kernels called from Python
    (``module.name``) that it compiled or loaded."""

    wall_s: float
    cpu_s: float
    kernels: frozenset[str]


WARMED = pytest.StashKey[Warmed]()  # on the config of the process that ran it


def entry_kernels() -> dict[str, object]:
    """The compiled kernels that Python code calls (``module.name`` -> numba dispatcher): the public
    names of ``KERNEL_MODULES``. The underscored ones are only called from other kernels and compiled
    inside them; loaded from the cache they are not loaded on their own."""
    import importlib

    from numba.core.registry import CPUDispatcher

    out = {}
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name and not attr.startswith("_"):
                out[f"{name}.{attr}"] = value
    return out


def compile_measuring_kernels() -> Warmed:
    """Measure the plane rig's doorway and a tilted wall with noise and outliers by every method (what
    runs each kernel of ``KERNEL_MODULES`` with the array types a measurement passes it)."""
    wall0, cpu0 = time.perf_counter(), time.process_time()
    from factories import doorway_frame, plane_frame
    from measure import MeasureOptions, measure_distance
    from measure.options import METHODS

    frames = (
        (doorway_frame(), (60, 120), (260, 120)),  # a gap: the line ends at two walls
        (plane_frame((0.2, 0.1, 1.0), 2.0, noise=0.2, outliers=0.05), (40, 100), (280, 140)),  # a surface, outliers
    )
    for frame, p1, p2 in frames:
        for method in METHODS:
            measure_distance(frame, p1, p2, MeasureOptions(method=method))
    reached = frozenset(name for name, kernel in entry_kernels().items() if kernel.signatures)
    return Warmed(time.perf_counter() - wall0, time.process_time() - cpu0, reached)
