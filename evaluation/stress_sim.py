"""Simulated stress study: segments across several surfaces, person height, posters, doorways.

Per (distance, seed) of the plan, on the simulated rig (``sim.scenario``, poster on its stand):

- ``room-wall-board-floor``: a column through the board, from a click near the top of the image
  (wall, or the board when it fills the view) to one near the bottom (floor);
- ``room-wall-floor``: a column beside the board, from the wall down to the floor (the crease);
- ``room-board-floor``: from a point on the board down to the floor;
  the room clicks land inside surfaces and their truth is the true depth at the clicked pixels;
- ``person``: height floor to head with the simulator's human clicks; truth the person's height;
- ``poster``: poster width and length with the simulator's clicks;
- ``doorway``: the door's width with the simulator's clicks: a gap (detection rate).

Seeds split into dev (``DEV_SEEDS``) and held-out (``HELD_OUT_SEEDS``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.stress import StressCase, StressRecord, measure_case

DISTANCES_M: tuple[float, ...] = (2.0, 3.0, 4.0, 5.0, 6.0, 7.0)
POSES: tuple[tuple[float, float], ...] = ((0.0, 0.0), (-20.0, 3.0), (20.0, -3.0))
DEV_SEEDS: tuple[int, ...] = (0, 1, 2, 3)
HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001, 1002, 1003)


def _truth_m(truth: Any, camera: Any, p1: tuple[float, float], p2: tuple[float, float]) -> float | None:
    pts = []
    for x, y in (p1, p2):
        z = float(truth.depth_m[int(y), int(x)])
        if not np.isfinite(z):
            return None
        pts.append(np.array([(x - camera.cx) * z / camera.fx, (y - camera.cy) * z / camera.fy, z]))
    return float(np.linalg.norm(pts[0] - pts[1]))


def room_cases(frame: Any, truth: Any, rng: np.random.Generator) -> list[StressCase]:
    """The three room segments of the module docstring on one poster frame (clicks inside surfaces)."""
    cam = frame.camera
    w, h = cam.width, cam.height
    # The board's image extent from its true end pixels (poster-width/length give two of its edges).
    z = truth.depth_m
    cx = int(round(0.5 * (truth.p1_px[0] + truth.p2_px[0])))
    board = np.isfinite(z[:, cx]) & (z[:, cx] < np.nanmedian(z[: max(3, h // 20), cx]) - 0.2)
    rows = np.flatnonzero(board)
    out: list[StressCase] = []

    def add(cond: str, p1, p2) -> None:
        t = _truth_m(truth, cam, p1, p2)
        if t is not None and t > 0:
            out.append(StressCase("room", cond, (float(p1[0]), float(p1[1])), (float(p2[0]), float(p2[1])), t))

    x = float(cx + rng.integers(-20, 21))
    y_top = float(rng.integers(3, max(4, h // 12)))
    y_bot = float(h - 1 - rng.integers(3, max(4, h // 12)))
    add("room-wall-board-floor", (x, y_top), (x, y_bot))
    xs = float(rng.integers(10, max(11, w // 8)))
    add("room-wall-floor", (xs, y_top), (xs, y_bot))
    if rows.size > 40:
        yb = float(rng.integers(rows[0] + 10, rows[0] + max(11, rows.size // 2)))
        add("room-board-floor", (x, yb), (x, y_bot))
    return out


def stress_sim_cases(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[tuple[Any, list[StressCase]]]:
    """(frame, cases) for every (seed, distance) of the plan; the pose cycles with the seed."""
    import sim

    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed + 7919)
        for i, dist in enumerate(distances):
            yaw, roll = POSES[(seed + i) % len(POSES)]
            s = int(seed) * 100 + i
            for target in ("poster-width", "poster-length"):
                frame, truth, (c1, c2) = sim.scenario("poster", target=target, distance_m=dist, seed=s, yaw_deg=yaw, roll_deg=roll)
                cases = [StressCase("poster", "poster", c1, c2, truth.length_m)]
                if target == "poster-width":
                    cases += room_cases(frame, truth, rng)
                out.append((frame, cases))
            frame, truth, (c1, c2) = sim.scenario("person", distance_m=dist, seed=s, yaw_deg=yaw, width=720, height=1280)
            out.append((frame, [StressCase("person", "person", c1, c2, truth.length_m)]))
            frame, truth, (c1, c2) = sim.scenario("doorway", distance_m=dist, seed=s, yaw_deg=yaw)
            out.append((frame, [StressCase("doorway", "doorway", c1, c2, truth.length_m, is_gap=True)]))
    return out


def run_stress_sim(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[StressRecord]:
    return [measure_case(f, c, "sim") for f, cases in stress_sim_cases(seeds, distances) for c in cases]


TITLE = "Simulated stress study"
NOTES = [
    "Simulated stress study (evaluation/stress_sim.py): room segments across wall, board "
    "and floor (clicks inside surfaces, truth from the true depth at the clicked pixels), person "
    f"height, posters, doorways (gaps); distances {', '.join(f'{d:g}' for d in DISTANCES_M)} m. "
    f"Dev seeds {list(DEV_SEEDS)}, held-out seeds {list(HELD_OUT_SEEDS)}.",
]


def write_stress_sim(out_dir: Path, dev: Sequence[StressRecord], held_out: Sequence[StressRecord], setup: dict[str, Any]) -> dict[str, Path]:
    from evaluation.stress import write_stress_report

    return write_stress_report(out_dir, TITLE, setup, {"dev": dev, "held-out": held_out}, NOTES)


def stress_sim_markdown(data: dict[str, Any]) -> str:
    """report.md from its results.json ``data``."""
    from evaluation.stress import stress_markdown

    return stress_markdown(TITLE, NOTES, data)
