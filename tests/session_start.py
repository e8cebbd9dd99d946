"""What a test session does once, before its first test: the measuring kernels compiled by numba, or
loaded from numba's disk cache when an earlier run wrote it (docs/testing.md, "Where the time goes").

Called by ``tests/conftest.py`` at the session's start in the process that starts the session: with
pytest-xdist that is the controller, before its workers start, so the workers load what it wrote
instead of each compiling the same kernels at once; a Ray or process-pool worker a test starts loads
them too. Without it the first test that measures carried the compile (about 11 s of CPU from a fresh
checkout, when no cache is on disk). The seconds it took are printed beside the tests' own with
``--durations`` (tests/cpu_times.py) and given as their own line in docs/test-times.md.
"""

from __future__ import annotations

import time


def compile_measuring_kernels() -> tuple[float, float]:
    """Measure the plane rig's doorway and a tilted wall with noise and outliers by every method (what
    runs each compiled kernel of ``measure.kernels`` and ``measure.fit_kernels`` with the array types
    a measurement passes it); returns the wall and CPU seconds it took."""
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
    return time.perf_counter() - wall0, time.process_time() - cpu0
