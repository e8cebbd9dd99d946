"""Speed of the simulated rig at 1280x720: a streamed frame, a scenario() call, a cold scene.

Run: ``.venv/bin/python bench/bench_sim.py`` or ``depthruler bench sim`` (``--write`` records the
table in bench/RESULTS.md). Absolute times depend on the machine, so each is also given as a ratio
to a reference run side by side in the same process: drawing one 1280x720 float32 Gaussian noise
field (the least any per-frame simulation must do).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from datetime import datetime, timezone

import numpy as np
from bench.results_file import machine, replace_section

SECTION = "## Simulated rig"


def _median_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def run(repeat: int = 30) -> dict[str, float]:
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
    results["cold scene (ray-cast + its render), ms"] = (time.perf_counter() - t0) * 1e3
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


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=30, help="timed calls per figure (default 30)")
    ap.add_argument("--write", action="store_true", help=f"record the table in bench/RESULTS.md ({SECTION!r})")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")
    load = os.getloadavg()[0]
    results = run(args.repeat)
    rows = [(k, v, results.get(k.replace(", ms", " / reference"))) for k, v in results.items() if k.endswith(", ms")]
    lines = [
        SECTION,
        "",
        "`bench/bench_sim.py` (`depthruler bench sim --write`): median of "
        f"{args.repeat} calls (the cold scene: one call, before anything is cached); the reference is one "
        "1280x720 float32 normal field drawn in the same process.",
        "",
        "| what | median ms | / reference |",
        "| --- | --- | --- |",
        *(f"| {k.removesuffix(', ms')} | {v:.1f} | {'' if r is None else f'{r:.1f}x'} |" for k, v, r in rows),
        "",
        f"Machine: {machine()}; {datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}; "
        f"1-minute load average {load:.2f} before.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.write:
        replace_section(SECTION, text)


if __name__ == "__main__":
    main()
