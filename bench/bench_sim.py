"""Speed of the simulated rig at 1280x720: a streamed frame, a scenario() call, a cold scene.

Run: ``.venv/bin/python bench/bench_sim.py``. Absolute times depend on the machine, so each is also
given as a ratio to a reference run side by side in the same process: drawing one 1280x720 float32
Gaussian noise field (the least any per-frame simulation must do).

Recorded 2026-11-23 on the 2-core build machine shared with ~6 jobs (load average ~5, so absolute
times are ~2-3x an idle machine's): sim source frame 1280x720 27-56 ms (1.8-4.0x reference),
scenario() 35-72 ms, scenario() + robust measurement 46-83 ms, cold scene 0.8-1.2 s (cached after).
"""

from __future__ import annotations

import statistics
import time

import numpy as np


def _median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main(repeat: int = 30) -> dict[str, float]:
    import sim
    from device import open_source
    from measure import MeasureOptions, measure_distance
    from sim.scenes import get_view

    rng = np.random.default_rng(0)
    reference = lambda: rng.standard_normal((720, 1280), dtype=np.float32)  # noqa: E731
    results: dict[str, float] = {}
    get_view.cache_clear()
    t0 = time.perf_counter()
    sim.scenario("person", distance_m=4.0)
    results["cold scene (ray-cast + 3 renders), ms"] = (time.perf_counter() - t0) * 1e3
    with open_source("sim:poster?distance=4&fps=0") as src:
        src.read()
        results["sim source frame 1280x720, ms"] = _median_ms(src.read, repeat)
    seeds = iter(range(10**6))
    results["scenario() 1280x720, ms"] = _median_ms(lambda: sim.scenario("boxes", distance_m=6.0, seed=next(seeds)), repeat)

    def one_eval():
        frame, _, (c1, c2) = sim.scenario("poster", distance_m=7.0, seed=next(seeds))
        measure_distance(frame, c1, c2, MeasureOptions(method="robust"))

    results["scenario() + robust measurement, ms"] = _median_ms(one_eval, repeat)
    ref = _median_ms(reference, repeat)
    results["reference: one 1280x720 normal field, ms"] = ref
    for key in list(results):
        if key.startswith("reference"):
            continue
        results[key.replace(", ms", " / reference")] = results[key] / ref
    return results


if __name__ == "__main__":
    for name, value in main().items():
        print(f"{name:45s} {value:9.2f}")
