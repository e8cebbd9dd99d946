"""The paper's targets on reduced runs of `depthruler eval`: the simulated rig (one measurement per
(measurement, distance, lighting) cell) and the Middlebury edge protocol, with their reports."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.eval import app
from evaluation.report import METHODS, PNG_SIGNATURE
from evaluation.sim_study import LIGHTINGS

# One measurement per cell of the 84 (equal counts per distance), plus 8 gap measurements: the
# targets below are the paper's, and hold at this size by a wide margin (the commit that set it has the figures).
SIM_N = 84


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("eval_sim")
    res = CliRunner().invoke(app, ["sim", "--out", str(out), "--measurements", str(SIM_N), "--seed", "11"])
    assert res.exit_code == 0, res.output + repr(res.exception)
    return out, json.loads((out / "results.json").read_text())


def _check_stats(s: dict) -> None:
    assert set(s) >= {"mean", "std", "n"}
    assert s["n"] > 0 and np.isfinite(s["mean"]) and s["std"] >= 0


@pytest.mark.slow
def test_sim_results_shape_and_files(sim_run):
    out, r = sim_run
    assert set(r["methods"]) == set(METHODS)
    for m in METHODS:
        mm = r["methods"][m]
        _check_stats(mm["overall"])
        assert set(mm["by_distance"]) == {"2", "4", "6", "7"}
        assert set(mm["by_lighting"]) == set(LIGHTINGS)
        for s in [*mm["by_distance"].values(), *mm["by_lighting"].values()]:
            _check_stats(s)
        assert sum(s["n"] for s in mm["by_distance"].values()) == mm["overall"]["n"]
    assert r["n_measurements"] == SIM_N and r["n_gap_measurements"] == round(0.1 * SIM_N)
    assert 0 <= r["gap"]["false_positive_rate"] <= 1 and 0 <= r["gap"]["detection_rate"] <= 1
    for m in METHODS:
        t = r["timing_ms"][m]
        assert 0 < t["median"] <= t["worst"]
    _check_report(out, ["accuracy_by_distance.png", "accuracy_vs_distance.png", "accuracy_by_lighting.png", "error_histogram.png"])
    rows = (out / "measurements.csv").read_text().splitlines()
    assert len(rows) == 1 + SIM_N + round(0.1 * SIM_N)


def _check_report(out: Path, plots: list[str]) -> None:
    md = (out / "report.md").read_text()
    for name in plots:
        data = (out / name).read_bytes()
        assert data[:8] == PNG_SIGNATURE and len(data) > 10_000, name
        assert f"]({name})" in md


@pytest.mark.slow
def test_sim_paper_beats_basic_as_published(sim_run):
    """The paper's result: +2.6 points overall, about +4 at 6-7 m, with a lower standard deviation."""
    _, r = sim_run
    basic, paper = r["methods"]["basic"], r["methods"]["paper"]
    assert paper["overall"]["mean"] - basic["overall"]["mean"] >= 2.6
    far = ("6", "7")  # equal counts per distance, so the pooled mean is the mean of the two
    gain_far = np.mean([paper["by_distance"][k]["mean"] - basic["by_distance"][k]["mean"] for k in far])
    assert gain_far >= 4.0
    assert paper["overall"]["std"] < basic["overall"]["std"]


@pytest.mark.slow
def test_sim_robust_beats_paper(sim_run):
    _, r = sim_run
    assert r["methods"]["robust"]["overall"]["mean"] > r["methods"]["paper"]["overall"]["mean"]


@pytest.mark.slow
def test_sim_gap_detector_false_positives(sim_run):
    """The paper: 6.8 % of 1873 non-gap measurements flagged as gaps."""
    _, r = sim_run
    assert r["gap"]["false_positive_rate"] <= 0.068, r["gap"]["false_positives_by_target"]


@pytest.mark.slow
def test_sim_gap_detector_finds_gaps(sim_run):
    _, r = sim_run
    assert r["gap"]["detection_rate"] >= 0.5, r["gap"]["detection_rate_by_scene"]


@pytest.fixture(scope="module")
def middlebury_run(tmp_path_factory, middlebury_dir) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("eval_middlebury")
    res = CliRunner().invoke(app, ["middlebury", "--data", str(middlebury_dir), "--out", str(out)])
    assert res.exit_code == 0, res.output + repr(res.exception)
    return out, json.loads((out / "results.json").read_text())


@pytest.mark.slow
def test_middlebury_results_and_targets(middlebury_run, middlebury_dir):
    out, r = middlebury_run
    scenes = sorted(p.name for p in middlebury_dir.iterdir() if (p / "im0.png").is_file())
    for cond in ("sgbm", "gt_contended"):
        ms = r["conditions"][cond]["methods"]
        assert set(ms) == set(METHODS)
        for m in METHODS:
            _check_stats(ms[m]["overall"])
            assert sorted(ms[m]["by_scene"]) == scenes
    assert sum(s["n_segments"] for s in r["setup"]["scenes"].values()) >= 30
    for s in r["setup"]["scenes"].values():
        assert s["sgbm_config"]["num_disparities"] % 16 == 0
    # Targets: robust median >= 95 and robust above basic by >= 8 points. basic's median
    # is high on these segments while its failures are gross, so the +8 is on the mean, and
    # robust must win on the median too (as tests/studies/test_middlebury_accuracy.py reads the target).
    sgbm = r["conditions"]["sgbm"]["methods"]
    robust, basic = sgbm["robust"]["overall"], sgbm["basic"]["overall"]
    assert robust["median"] >= 95.0
    assert robust["median"] >= basic["median"]
    assert robust["mean"] >= basic["mean"] + 8.0
    _check_report(
        out,
        [
            "accuracy_by_scene_sgbm.png",
            "accuracy_by_scene_gt_contended.png",
            "error_histogram_sgbm.png",
            "error_histogram_gt_contended.png",
            "segments.png",
        ],
    )
