"""The stress protocol's targets on a reduced run (dev data only): coverage of the truth, the gap rule's
false positives, segments across several surfaces, and "good" answers that are right."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.stress import by_scene, figures, measure_case, worst_scene
from evaluation.stress_middlebury import DEV_SCENES, run_stress_middlebury
from factories import boxes_frame
from measure import MeasureOptions, measure_distance

SCENES = DEV_SCENES  # dev scenes only


@pytest.fixture(scope="module")
def middlebury_stress(middlebury_dir):
    assert set(SCENES) <= set(DEV_SCENES)
    return run_stress_middlebury(middlebury_dir, SCENES, disparities=("sgbm", "gt_out50"))


@pytest.fixture(scope="module")
def sim_stress(stress_sim_frames):
    """evaluation.stress_sim.run_stress_sim((0, 1), (3.0, 5.0)), on the frames test_core_answers answers too."""
    return [measure_case(f, c, "sim") for f, cases in stress_sim_frames for c in cases]


@pytest.mark.parametrize("disparity", ["sgbm", "gt_out50"])
def test_good_answers_are_right_and_common(middlebury_stress, disparity):
    f = figures([r for r in middlebury_stress if r.disparity == disparity])
    assert f["n"] >= 100
    assert f["good"] >= 0.5, f
    assert f["good_and_A_below_90"] <= 0.05, f
    assert f["cov_2sigma_among_good"] >= 0.8, f


def test_no_dev_scene_is_confidently_wrong_with_the_projects_sgbm(middlebury_stress):
    # Every scene at most 5 % "good" answers with A < 90, all together at most 2 %, and 2σ covers at
    # least 85 % of the good ones (the per-scene table of the stress report).
    sgbm = [r for r in middlebury_stress if r.disparity == "sgbm"]
    scenes = by_scene(sgbm)
    assert {name.split("/", 1)[1] for name in scenes} == set(SCENES)
    assert all(f["good_and_A_below_90"] <= 0.05 for f in scenes.values()), worst_scene(scenes, "sgbm")
    f = figures(sgbm)
    assert f["good_and_A_below_90"] <= 0.02, f
    assert f["good"] >= 0.5, f
    assert f["cov_2sigma_among_good"] >= 0.85, f


def test_uncertainty_covers_the_truth_on_sgbm(middlebury_stress):
    f = figures([r for r in middlebury_stress if r.disparity == "sgbm"])
    # The target was 60-76 % within 1σ; the upper bound is wider since extrapolated ends take their click
    # windows (measure.robust._observed_ends): docs/decisions/model-selection.md, "Not reached".
    assert 0.6 <= f["cov_1sigma"] <= 0.82, f
    assert 0.9 <= f["cov_2sigma"] <= 0.98, f
    assert f["cov_interval"] >= 0.9, f
    assert all(r.sigma_m > 0 for r in middlebury_stress if np.isfinite(r.robust_m))


def test_robust_is_rarely_much_worse_than_basic(middlebury_stress):
    # The target: <= 1 % (docs/decisions/extrapolated-ends.md and line-estimator.md measure what got
    # SGBM and GT + 50 % outliers there).
    for disparity, limit in (("sgbm", 0.01), ("gt_out50", 0.01)):
        recs = [r for r in middlebury_stress if r.disparity == disparity]
        assert figures(recs)["robust_much_worse_than_basic"] <= limit
        worse = [r for r in recs if r.robust_m < 0.9 * r.case.truth_m or r.robust_m > 1.1 * r.case.truth_m]
        # and such answers do not claim to be good
        assert sum(r.quality == "good" for r in worse) <= 0.05 * len(recs)


def test_gap_rule_does_not_fire_without_a_gap(middlebury_stress):
    for disparity in ("sgbm", "gt_out50"):
        nogap = [r for r in middlebury_stress if r.case.condition == "nogap" and r.disparity == disparity]
        assert len(nogap) >= 20
        assert figures(nogap)["gap_rate_no_gap"] <= 0.03, disparity
    # A recessed surface between two nearer ones is a gap's geometry; its truth here is the recessed
    # surface. A gap answer's sigma leaves that reading out (docs/decisions/gap-sigma.md): it may be
    # "good", but rarely so when wrong.
    recess = [r for r in middlebury_stress if r.case.condition == "recess"]
    assert len(recess) >= 10
    wrong = [r for r in recess if r.gap and r.quality == "good" and abs(r.robust_m - r.case.truth_m) > 0.1 * r.case.truth_m]
    assert len(wrong) <= 0.05 * len(recess), wrong


def test_gap_between_boxes_is_found_on_evidence_not_a_fixed_step():
    """A 20 % deeper background (the simulator's floor behind its boxes at 3 m): both ends' surfaces
    are 1.6 px in front of the segment's, dozens of correlation-inflated standard errors, so it is a
    gap (the first pass needed the ends 20 % nearer in depth, 16.7 % here). A 5 % step is not."""
    p1, p2 = (146.0, 100.0), (254.0, 100.0)
    z = 500.0 * 0.06 / 9.4
    truth = (p2[0] - p1[0]) * z / 500.0
    for seed in range(3):
        m = measure_distance(boxes_frame(0.2, seed), p1, p2)
        assert m.gap_detected and "gap detected" in m.reasons, m
        assert abs(m.distance_m - truth) / truth < 0.02, (m.distance_m, truth)
        # Its sigma is that of the end surfaces and the clicks, and covers the truth.
        assert abs(m.distance_m - truth) <= 2 * m.uncertainty_m <= 0.1 * truth, m
        flat = measure_distance(boxes_frame(0.05, seed), p1, p2)
        assert not flat.gap_detected


def test_every_answer_has_a_verdict(middlebury_stress):
    for r in middlebury_stress:
        if np.isfinite(r.robust_m):
            assert r.quality in ("good", "check", "unreliable")
            assert r.lo_m <= r.robust_m <= r.hi_m


def test_several_surfaces_in_simulated_rooms(sim_stress):
    rooms = [r for r in sim_stress if r.case.group == "room"]
    f = figures(rooms)
    assert f["good_and_A_below_90"] <= 0.05, f
    # Better than one straight line through wall, board and floor (mean A about 80 before), and within
    # a point of the window medians (basic) on average.
    assert f["median_A"] >= 95.0, f
    assert f["mean_A"] >= f["basic_mean_A"] - 1.0, f
    crossing = [r for r in rooms if r.fit == "surfaces"]
    assert crossing and all("segment crosses several surfaces" in r.reasons for r in crossing)


def test_person_height_and_doorways(sim_stress):
    person = [r for r in sim_stress if r.case.condition == "person"]
    err = np.array([abs(r.robust_m - r.case.truth_m) / r.case.truth_m for r in person])
    assert err.mean() <= 0.03, err
    doors = figures([r for r in sim_stress if r.case.condition == "doorway"])
    assert doors["gap_rate_gap"] >= 0.75, doors


def test_person_height_within_two_percent_on_dev_seeds():
    # The target: floor-to-head within 2 % on average; the dev seeds and distances of the stress study
    # (evaluation/stress_sim.py), 24 people. One straight line through the body's front is too long
    # (the head's top and the shoe's front are off that line); the ends take their nearest samples'
    # level when it is two standard errors off (measure.surfaces; docs/decisions/end-surfaces.md).
    import sim

    from evaluation.stress_sim import DEV_SEEDS, DISTANCES_M, POSES

    err = []
    for seed in DEV_SEEDS:
        for i, dist in enumerate(DISTANCES_M):
            yaw, _ = POSES[(seed + i) % len(POSES)]
            frame, truth, (c1, c2) = sim.scenario("person", distance_m=dist, seed=int(seed) * 100 + i, yaw_deg=yaw, width=720, height=1280)
            err.append((measure_distance(frame, c1, c2).distance_m - truth.length_m) / truth.length_m)
    assert np.abs(err).mean() <= 0.02, err


def test_wall_to_floor_through_a_board_is_not_confidently_wrong():
    import sim

    frame, truth, _ = sim.scenario("poster", distance_m=4.0, seed=1)
    p1, p2 = (640.0, 40.0), (640.0, 660.0)
    z = truth.depth_m
    cam = frame.camera
    pts = [np.array([(x - cam.cx) * z[int(y), int(x)] / cam.fx, (y - cam.cy) * z[int(y), int(x)] / cam.fy, z[int(y), int(x)]]) for x, y in (p1, p2)]
    g = float(np.linalg.norm(pts[0] - pts[1]))
    for method in ("robust", "paper", "basic"):
        m = measure_distance(frame, p1, p2, MeasureOptions(method=method))
        assert m.quality in ("good", "check", "unreliable")
        lo, hi = m.interval_m
        assert m.quality != "good" or lo <= g <= hi, (method, m.distance_m, m.interval_m, g)
    m = measure_distance(frame, p1, p2)
    assert abs(m.distance_m - g) / g < 0.05
    assert "segment crosses several surfaces" in m.reasons
    assert m.to_dict()["quality"] == m.quality and m.to_dict()["interval_m"] == list(m.interval_m)


def test_stress_protocol_command_writes_tables_and_plots(tmp_path, middlebury_dir):
    import json

    from typer.testing import CliRunner

    from cli.eval import app
    from evaluation.report import PNG_SIGNATURE

    out = tmp_path / "stress"
    res = CliRunner().invoke(app, ["middlebury", "--protocol", "stress", "--data", str(middlebury_dir), "--scene", "Piano", "--max-segments", "2", "--out", str(out)])
    assert res.exit_code == 0, res.output + repr(res.exception)
    data = json.loads((out / "results.json").read_text())
    figs = data["splits"]["dev"]["figures"]
    assert {"sgbm/exact", "bm/jitter", "gt_out50/nogap", "sgbm/all"} <= set(figs)
    assert (out / "stress_dev.png").read_bytes()[:8] == PNG_SIGNATURE
    text = (out / "report.md").read_text()
    assert "good & A<90" in text and "dev-scenes" in text and "Worst scene by good & A<90: sgbm Piano" in text
    assert set(data["splits"]["dev"]["scenes"]) == {"sgbm/Piano", "bm/Piano", "gt_out50/Piano"}
    bad = CliRunner().invoke(app, ["middlebury", "--protocol", "nonsense", "--data", str(middlebury_dir), "--out", str(out)])
    assert bad.exit_code != 0 and "edge or stress" in bad.output
