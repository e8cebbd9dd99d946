"""Speed work on the measurement core keeps its answers: today's default answers on the reduced stress
and edge protocols (``evaluation.core_answers``) against the stored ones of the code before it
(tests/fixtures/core_answers.json, written by ``python -m evaluation.core_answers --write``), each
within 0.05 points of A (Eq. 8), with the same verdict, fit and gap flag."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from evaluation.core_answers import _cases, _row

STORED = Path(__file__).resolve().parents[1] / "fixtures" / "core_answers.json"
TOLERANCE_A = 0.05


def _compare(protocols: set[str], middlebury_dir: Path | None, sim_cases: list | None = None) -> None:
    stored = {(r["protocol"], r["key"]): r for r in json.loads(STORED.read_text()) if r["protocol"] in protocols}
    now = [_row(*c) for c in _cases(middlebury_dir, sim_cases, frozenset(protocols))]
    assert {(r["protocol"], r["key"]) for r in now} == set(stored)
    worst = 0.0
    for r in now:
        old = stored[(r["protocol"], r["key"])]
        assert (r["p1"], r["p2"]) == (old["p1"], old["p2"]), r["key"]
        if math.isnan(old["distance_m"]):
            assert math.isnan(r["distance_m"]) and r["error"] == old["error"], r
            continue
        delta_a = 100.0 * abs(r["distance_m"] - old["distance_m"]) / r["truth_m"]
        worst = max(worst, delta_a)
        assert delta_a <= TOLERANCE_A, (r, old)
        assert (r["quality"], r["fit"], r["gap"]) == (old["quality"], old["fit"], old["gap"]), (r, old)
    print(f"{sorted(protocols)}: {len(now)} answers, largest change {worst:.4f} A points")


def test_simulated_stress_and_rooms_keep_their_answers(stress_sim_frames):
    _compare({"stress-sim", "rooms"}, None, stress_sim_frames)


@pytest.mark.slow
def test_middlebury_stress_and_edge_keep_their_answers(middlebury_dir):
    _compare({"stress-middlebury", "edge-middlebury"}, middlebury_dir)
