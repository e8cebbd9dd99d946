"""Gaps clicked at their true edges (`depthruler eval gaps`): the simulator's doorway and the gap between
two boxes, at ``DISTANCES_M``, each measured by ``robust`` and ``basic`` in three conditions:

- ``sim-exact-clicks``: the clicks on the true end pixels (``sim.Truth.p1_px`` / ``p2_px``) and stated
  exact (``click_px=0``): the sigma is the end surfaces' alone, the condition whose coverage counts;
- ``sim``: the same clicks with the default click sigma (a person's 1.5 px, which such clicks do not
  have, so its intervals are wider than the errors);
- ``sim-jittered-clicks``: each click moved by ``JITTER_PX`` (one sigma, per axis, Gaussian) from the true
  end pixel, with the default click sigma: clicks as uncertain as the answer says they are.

Seeds split into dev and held-out; ``notes`` gives each condition's 2σ coverage with its 95 % Wilson
interval and the median sigma by distance."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from evaluation.report import wilson
from evaluation.stress import StressCase, StressRecord, measure_case

DISTANCES_M: tuple[float, ...] = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
DEV_SEEDS: tuple[int, ...] = tuple(range(12))
HELD_OUT_SEEDS: tuple[int, ...] = tuple(range(1000, 1012))
CASES: tuple[tuple[str, str], ...] = (("doorway", "doorway"), ("boxes", "box-gap"))
JITTER_PX = 1.5  # the default MeasureOptions.click_px
CONDITIONS: tuple[str, ...] = ("sim", "sim-exact-clicks", "sim-jittered-clicks")


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
                # The jitter's own stream: the frame's noise stays the seed's.
                rng = np.random.default_rng([seed, 7919])
                j1, j2 = (tuple(float(v) for v in np.asarray(p) + rng.normal(0.0, JITTER_PX, 2)) for p in (truth.p1_px, truth.p2_px))
                out.append(measure_case(frame, StressCase(scene, case.condition, j1, j2, truth.length_m, is_gap=True), "sim-jittered-clicks"))
    return out


def notes(split: str, records: Sequence[StressRecord]) -> list[str]:
    """Per condition: 2σ coverage k / n with its Wilson interval, and the median sigma (mm) per scene and distance."""
    out = []
    for cond in CONDITIONS:
        rs = [r for r in records if r.disparity == cond and math.isfinite(r.robust_m)]
        k = sum(abs(r.robust_m - r.case.truth_m) <= 2.0 * r.sigma_m for r in rs)
        lo, hi = wilson(k, len(rs))
        sig = "; ".join(
            f"{scene} " + " / ".join(f"{1e3 * float(np.median([r.sigma_m for r in rs if r.case.condition == f'{scene}-{d:g}m'])):.1f}"
                                     for d in DISTANCES_M)
            for scene, _ in CASES
        )
        out.append(f"{split} {cond}: 2σ covers {k} of {len(rs)} ({100 * k / max(1, len(rs)):.1f} %, 95 % Wilson {100 * lo:.1f}-{100 * hi:.1f} %); "
                   f"median σ (mm) at {' / '.join(f'{d:g}' for d in DISTANCES_M)} m: {sig}")
    return out
