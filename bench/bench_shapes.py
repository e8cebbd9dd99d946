"""Benchmark: the shape measurements on a 1280x720 frame of a simulated box on a floor.

Times ``measure_box`` (a click on the top face), ``measure_height`` (the same click, above the plane
found under it) and ``measure_area`` (a polygon inside the top face), each against the segment
along the top face's diagonal (``measure_distance``) timed alongside in blocks, so the ratio to a
segment is the steadier figure on this shared host. CPU time of this process, one BLAS and one OpenCV thread.
Run: ``python -m bench.bench_shapes`` or ``depthruler bench shapes``; ``--runs 3 --write`` records
the table in bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import time
from datetime import datetime, timezone

import numpy as np

from bench.results_file import machine, replace_section

W, H = 1280, 720
SEEDS = (4, 9)  # plain boxes on a floor at 1.1 and 1.06 m (sim.shapes draws)
TARGETS_MS = {"box": 50.0, "height": 10.0, "area": 10.0}
SECTION = "## Shapes: speed"
HEADER = ("| run | box seed | shape | CPU median / p90 ms | wall median ms | segment CPU median ms | x segment | target ms |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- |")


def _cpu_wall(fn) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return (time.process_time() - c0) * 1e3, (time.perf_counter() - t0) * 1e3


def calls(seed: int) -> dict:
    """The shape calls and their reference segment on the box case of ``seed``."""
    from measure import measure_distance
    from measure.area import measure_area
    from measure.box import measure_box
    from measure.height import measure_height
    from sim.shapes import box_case

    case = box_case(seed, "stress", range_m=None, variant="plain", width=W, height=H)
    f, click = case.frame, case.click_px
    c = np.array(case.corners_px)
    centre = c.mean(axis=0)
    inner = [tuple(centre + 0.7 * (p - centre)) for p in c]
    return {
        "box": lambda: measure_box(f, click),
        "height": lambda: measure_height(f, click),
        "area": lambda: measure_area(f, inner),
        "segment": lambda: measure_distance(f, inner[0], inner[2]),
    }


def run(repeats: int = 15) -> list[dict]:
    """Per seed and shape: CPU and wall ms of ``repeats`` calls, interleaved with the segment's."""
    import cv2
    from threadpoolctl import threadpool_limits

    rows = []
    threads = cv2.getNumThreads()
    # One OpenCV thread too: its pool's threads add their CPU time to the process's (more than the wall
    # time they save on this 2-core host), which would count the same work more than once.
    cv2.setNumThreads(1)
    try:
        with threadpool_limits(1):
            for seed in SEEDS:
                rows += _seed_rows(seed, repeats)
    finally:
        cv2.setNumThreads(threads)
    return rows


def _seed_rows(seed: int, repeats: int) -> list[dict]:
    fns = calls(seed)
    for fn in fns.values():  # warm-up
        fn()
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            times[k].append(_cpu_wall(fn))
    seg = np.array(times["segment"])
    rows = []
    for k in ("box", "height", "area"):
        t = np.array(times[k])
        rows.append({"seed": seed, "shape": k, "cpu_median_ms": float(np.median(t[:, 0])),
                     "cpu_p90_ms": float(np.percentile(t[:, 0], 90)), "wall_median_ms": float(np.median(t[:, 1])),
                     "segment_cpu_ms": float(np.median(seg[:, 0])),
                     "ratio": float(np.median(t[:, 0]) / np.median(seg[:, 0]))})
    return rows


def _row(run_no: int, r: dict) -> str:
    return (f"| {run_no} | {r['seed']} | {r['shape']} | {r['cpu_median_ms']:.1f} / {r['cpu_p90_ms']:.1f} | {r['wall_median_ms']:.1f} | "
            f"{r['segment_cpu_ms']:.1f} | {r['ratio']:.1f}x | {TARGETS_MS[r['shape']]:g} |")


def report(runs: list[list[dict]], load: tuple[float, float], date: str) -> str:
    """The RESULTS.md section: every run's rows, the machine, and which targets hold."""
    met = {k: all(r["cpu_median_ms"] <= TARGETS_MS[k] for rows in runs for r in rows if r["shape"] == k) for k in TARGETS_MS}
    lines = [SECTION, "",
             "`bench/bench_shapes.py` (`depthruler bench shapes --runs N --write`): a simulated box on a floor "
             f"(`sim.shapes.box_case`, stress profile, seeds {', '.join(map(str, SEEDS))}), 1280x720; `measure_box` at the click on "
             "its top face, `measure_height` at the same click, `measure_area` of a polygon at 70 % of the top face; "
             "each call interleaved with the segment along the polygon's diagonal (`measure_distance`), whose time is the "
             "reference (x segment). CPU time of this process, one BLAS and one OpenCV thread, median of the timed calls after a warm-up. "
             "Targets (issue \"Measure shapes\"): box <= 50 ms, height and area <= 10 ms.", "", HEADER,
             *(_row(i + 1, r) for i, rows in enumerate(runs) for r in rows), "",
             f"Machine: {machine()}, numpy {np.__version__}; {date}; 1-minute load average {load[0]:.2f} before, {load[1]:.2f} after.",
             "", "Targets met in every run: " + ", ".join(f"{k} {'yes' if ok else 'no'}" for k, ok in met.items()) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1, help="repeat the whole benchmark this many times (default 1)")
    ap.add_argument("--repeats", type=int, default=15, help="timed calls of each shape per run and seed (default 15)")
    ap.add_argument("--write", action="store_true", help=f"record the table in bench/RESULTS.md ({SECTION!r})")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.repeats < 1:
        ap.error("--runs and --repeats must be at least 1")
    load_before = os.getloadavg()[0]
    print(HEADER)
    runs = []
    for i in range(args.runs):
        rows = run(args.repeats)
        runs.append(rows)
        for r in rows:
            print(_row(i + 1, r), flush=True)
    text = report(runs, (load_before, os.getloadavg()[0]), datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"))
    print(text.rstrip().split("\n")[-1])
    if args.write:
        replace_section(SECTION, text)
        print(f"recorded in bench/RESULTS.md ({SECTION})")


if __name__ == "__main__":
    main()
