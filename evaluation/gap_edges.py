"""Gaps clicked at their true edges (`depthruler eval gaps`): the simulator's doorway and the gap between
two boxes, at ``DISTANCES_M``, the clicks on the true end pixels (``sim.Truth.p1_px`` / ``p2_px``), each
measured by ``robust`` and ``basic`` twice: with the default click sigma (``sim``: a person's 1.5 px,
which such exact clicks do not have, so its intervals are wider than the errors) and with the clicks
stated exact (``sim-exact-clicks``: ``click_px=0``, the sigma the end surfaces' alone, the one whose
coverage is meaningful here). Seeds split into dev and held-out."""

from __future__ import annotations

from collections.abc import Sequence

from evaluation.stress import StressCase, StressRecord, measure_case

DISTANCES_M: tuple[float, ...] = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
DEV_SEEDS: tuple[int, ...] = (0, 1, 2, 3, 4, 5)
HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001, 1002)
CASES: tuple[tuple[str, str], ...] = (("doorway", "doorway"), ("boxes", "box-gap"))


def run_gap_edges(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[StressRecord]:
    import sim
    from measure import MeasureOptions

    out = []
    for scene, target in CASES:
        for dist in distances:
            for seed in seeds:
                frame, truth, _ = sim.scenario(scene, target=target, distance_m=dist, seed=seed)
                case = StressCase(scene, f"{scene}-{dist:g}m", truth.p1_px, truth.p2_px, truth.length_m, is_gap=True)
                out.append(measure_case(frame, case, "sim"))
                out.append(measure_case(frame, case, "sim-exact-clicks", MeasureOptions(click_px=0.0)))
    return out
