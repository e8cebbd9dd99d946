"""Answers of the default method on reduced stress and edge protocols, to hold a speed change to them.

``core_answers`` measures (robust, the default options) a fixed, reduced set of click pairs: the
simulated stress protocol (``evaluation.stress_sim``, seeds 0-1 at 3 and 5 m), the wall/board-to-floor
rooms (``evaluation.bent_rooms``, seeds 500-502), and on the dev Middlebury scenes Adirondack and Piano
(when the scenes are present) the Middlebury stress protocol (SGBM and ground truth with 50 % outliers,
4 segments a scene) and the edge protocol (SGBM and contended ground truth, exact and jittered end
pixels, 6 segments). Each answer is a row: protocol, case key, truth (m), distance (m, NaN when the
method raised), one-sigma (m), verdict, fit and gap flag.

``python -m evaluation.core_answers --write PATH`` stores the rows as JSON (the fixture
``tests/fixtures/core_answers.json`` is made this way, by the code before a change that must keep
its answers); tests/studies/test_core_answers.py compares today's answers with it in A points (Eq. 8).
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

SIM_SEEDS, SIM_DISTANCES = (0, 1), (3.0, 5.0)
ROOM_SEEDS = (500, 501, 502)
SCENES = ("Adirondack", "Piano")
STRESS_SEGMENTS, EDGE_SEGMENTS = 4, 6
PROTOCOLS = frozenset({"stress-sim", "rooms", "stress-middlebury", "edge-middlebury"})


def _row(protocol: str, key: str, frame: Any, p1, p2, truth: float) -> dict[str, Any]:
    from measure import MeasureError, measure_distance

    base = {"protocol": protocol, "key": key, "p1": list(p1), "p2": list(p2), "truth_m": float(truth)}
    try:
        m = measure_distance(frame, p1, p2)
    except MeasureError as exc:
        return base | {"distance_m": math.nan, "sigma_m": math.nan, "quality": "", "fit": "", "gap": False, "error": str(exc)}
    return base | {"distance_m": float(m.distance_m), "sigma_m": float(m.uncertainty_m), "quality": m.quality,
                   "fit": m.fit, "gap": bool(m.gap_detected), "error": ""}


def _cases(middlebury_dir: Path | None, sim_cases: list[tuple[Any, list]] | None = None,
           protocols: frozenset[str] = PROTOCOLS) -> Iterator[tuple[str, str, Any, Any, Any, float]]:
    """Every (protocol, key, frame, p1, p2, truth) to answer of ``protocols`` (the others' frames are not
    made); ``sim_cases``: the simulated stress frames and cases (``stress_sim_cases(SIM_SEEDS, SIM_DISTANCES)``)
    when the caller has them already."""
    from evaluation.bent_rooms import room_cases
    from evaluation.stress_sim import stress_sim_cases

    unknown = sorted(set(protocols) - PROTOCOLS)
    if unknown:
        raise ValueError(f"unknown protocol(s) {', '.join(unknown)}; use any of {', '.join(sorted(PROTOCOLS))}")
    if "stress-sim" in protocols:
        for i, (frame, cases) in enumerate(stress_sim_cases(SIM_SEEDS, SIM_DISTANCES) if sim_cases is None else sim_cases):
            for j, c in enumerate(cases):
                yield "stress-sim", f"{i}.{j}.{c.condition}", frame, c.p1_px, c.p2_px, c.truth_m
    if "rooms" in protocols:
        for i, (frame, cases) in enumerate(room_cases(ROOM_SEEDS)):
            for j, c in enumerate(cases):
                yield "rooms", f"{i}.{j}.{c.condition}", frame, c.p1_px, c.p2_px, c.truth_m
    if middlebury_dir is None or not protocols & {"stress-middlebury", "edge-middlebury"}:
        return
    from device.sources.middlebury import load_scene, scene_frame, scene_sgbm_config
    from device.sources.sgbm import compute_disparity
    from evaluation.middlebury import ClickJitter, ContentionModel, _segments, clicks_for, contended_disparity
    from evaluation.stress_middlebury import outlier_disparity, stress_cases

    for name in SCENES:
        scene = load_scene(middlebury_dir / name)
        rng = np.random.default_rng([0, sum(map(ord, name))])
        cases = stress_cases(scene, rng, STRESS_SEGMENTS)
        disp, conf = compute_disparity(scene.left, scene.right, scene_sgbm_config(scene))
        frames = {"sgbm": scene_frame(scene, disp, conf), "gt_out50": scene_frame(scene, outlier_disparity(scene.gt_disparity, 0.5, rng))}
        for source, frame in frames.items():
            for j, c in enumerate(cases):
                yield "stress-middlebury", f"{name}.{source}.{j}.{c.condition}", frame, c.p1_px, c.p2_px, c.truth_m
        degraded, _ = contended_disparity(scene.gt_disparity, scene.left, ContentionModel())
        edge_frames = {"sgbm": frames["sgbm"], "gt_contended": scene_frame(scene, degraded)}
        jitter = ClickJitter()
        crng = np.random.default_rng([jitter.seed, sum(map(ord, name))])
        pairs = [(c1, c2, t) for p1, p2, t in _segments(scene, EDGE_SEGMENTS)
                 for c1, c2 in clicks_for(p1, p2, jitter, crng, scene.camera.width, scene.camera.height)]
        for source, frame in edge_frames.items():
            for j, (c1, c2, t) in enumerate(pairs):
                yield "edge-middlebury", f"{name}.{source}.{j}", frame, c1, c2, t


def core_answers(middlebury_dir: Path | None = None) -> list[dict[str, Any]]:
    """One row (module docstring) per click pair; the Middlebury protocols only with ``middlebury_dir``."""
    return [_row(protocol, key, frame, p1, p2, truth) for protocol, key, frame, p1, p2, truth in _cases(middlebury_dir)]


def main(argv: list[str] | None = None) -> None:
    from evaluation.middlebury_data import default_data_dir

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", type=Path, required=True, help="JSON file to write the rows to")
    args = ap.parse_args(argv)
    root = default_data_dir()
    rows = core_answers(root if all((root / s / "im0.png").is_file() for s in SCENES) else None)
    # One row a line: a change of answers shows as the changed lines.
    args.write.write_text("[\n" + ",\n".join(json.dumps(r) for r in rows) + "\n]\n")
    print(f"{len(rows)} answers written to {args.write}")


if __name__ == "__main__":
    main()
