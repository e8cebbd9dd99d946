"""Gaps clicked at their true edges (`depthruler eval gaps`): the simulator's doorway and the gap between
two boxes, at ``DISTANCES_M``, the clicks on the true end pixels (``sim.Truth.p1_px`` / ``p2_px``), each
measured by ``robust`` (default options) and ``basic``. Seeds split into dev and held-out."""

from __future__ import annotations

from collections.abc import Sequence

from evaluation.stress import StressCase, StressRecord, measure_case

DISTANCES_M: tuple[float, ...] = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
DEV_SEEDS: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001, 1002)
CASES: tuple[tuple[str, str], ...] = (("doorway", "doorway"), ("boxes", "box-gap"))


def run_gap_edges(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[StressRecord]:
    import sim

    out = []
    for scene, target in CASES:
        for dist in distances:
            for seed in seeds:
                frame, truth, _ = sim.scenario(scene, target=target, distance_m=dist, seed=seed)
                case = StressCase(scene, f"{scene}-{dist:g}m", truth.p1_px, truth.p2_px, truth.length_m, is_gap=True)
                out.append(measure_case(frame, case, "sim"))
    return out
