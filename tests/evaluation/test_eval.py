"""The evaluation reports: protocol, statistics, outlier model, and the paper's targets on reduced runs."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.eval import app
from evaluation.middlebury import ContentionModel, contended_disparity, contended_regions
from evaluation.sim_study import DISTANCES_M, LIGHTINGS, MEASUREMENT_SET, dimension, plan_sim
from evaluation.report import METHODS, PNG_SIGNATURE, EvalError, summary
from measure.metrics import accuracy

SIM_N = 252  # the reduced run: 84 cells x 3 (equal counts per distance), plus 25 gap measurements


def test_accuracy_is_eq8():
    assert accuracy(2.0, 1.9) == pytest.approx(95.0)
    assert accuracy(2.0, 2.1) == pytest.approx(95.0)
    assert accuracy(1.0, 3.0) == pytest.approx(-100.0)  # not clipped
    s = summary(np.array([90.0, 100.0, np.nan]))
    assert s == {"mean": 95.0, "std": pytest.approx(np.sqrt(50.0)), "median": 95.0, "within_5pct": 0.5, "n": 2}
    assert summary(np.array([]))["n"] == 0


def test_plan_spreads_evenly_over_cells():
    jobs = plan_sim(1800, seed=3)
    plain = [j for j in jobs if not j.gap_scene]
    gaps = [j for j in jobs if j.gap_scene]
    assert len(plain) == 1800 and len(gaps) == 180
    cells = Counter((j.target, j.distance_m, j.lighting) for j in plain)
    assert len(cells) == len(MEASUREMENT_SET) * len(DISTANCES_M) * len(LIGHTINGS) == 84
    assert set(cells.values()) == {21, 22}  # 1800 = 21 x 84 + 36
    # The paper's set of seven: each dimension of the poster three times for one person's height.
    assert Counter(dimension(j.target) for j in plain) == {"poster-width": 772, "poster-length": 771, "person-height": 257}
    assert Counter(j.distance_m for j in plain) == {2.0: 455, 4.0: 449, 6.0: 448, 7.0: 448}
    assert Counter(j.scene for j in gaps) == {"doorway": 90, "boxes": 90}
    assert len({j.seed for j in jobs}) == len(jobs)
    assert plan_sim(1800, seed=3) == jobs
    assert {j.seed for j in plan_sim(1800, seed=4)}.isdisjoint({j.seed for j in jobs})


@pytest.mark.parametrize("n, frac", [(0, 0.1), (10, -0.1), (10, 1.5)])
def test_plan_rejects_bad_arguments(n, frac):
    with pytest.raises(EvalError, match="must"):
        plan_sim(n, gap_fraction=frac)


def test_contention_model_on_a_synthetic_step():
    h, w = 120, 160
    gt = np.full((h, w), 20.3, np.float32)
    gt[:, 80:] = 40.7  # one depth edge at x = 80
    gt[:5, :5] = np.nan
    rng = np.random.default_rng(1)
    image = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)  # textured everywhere
    image[90:, :40] = 128  # one flat patch: low texture
    model = ContentionModel(seed=7)
    region = contended_regions(gt, image, model)
    assert region[:, 80 - model.edge_band_px : 80 + model.edge_band_px].all()
    assert region[95:, 5:35].all()
    assert not region[30:80, 20:60].any()
    disp, outliers = contended_disparity(gt, image, model)
    assert disp.dtype == np.float32 and np.isnan(disp[:5, :5]).all()
    known = np.isfinite(disp)
    assert np.array_equal(disp[known], np.round(disp[known]))  # integer disparity
    clean = ~outliers & known
    assert np.array_equal(disp[clean], np.round(gt[clean]))
    assert not outliers[~region].any()
    frac = outliers[region & known].mean()
    assert abs(frac - 0.5) < 0.03
    assert disp[outliers].min() >= 20 and disp[outliers].max() <= 41
    again, _ = contended_disparity(gt, image, model)
    assert np.array_equal(again, disp, equal_nan=True)


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


def _said(output: str) -> str:
    """The CLI's message without rich's box drawing and line wrapping."""
    return " ".join(output.replace("│", " ").split())


def test_middlebury_bad_arguments(tmp_path, middlebury_dir):
    runner = CliRunner()
    res = runner.invoke(app, ["middlebury", "--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "does not exist; pass --data" in _said(res.output)
    res = runner.invoke(app, ["middlebury", "--data", str(middlebury_dir), "--scene", "Nope", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "scene(s) Nope not found" in _said(res.output)
    assert not (tmp_path / "o").exists()


def test_middlebury_data_defaults_to_depthruler_shared(tmp_path, monkeypatch):
    monkeypatch.setenv("DEPTHRULER_SHARED", "/no-such-dr")  # short: the error box must not wrap it
    for protocol in ("edge", "stress"):
        res = CliRunner().invoke(app, ["middlebury", "--protocol", protocol, "--out", str(tmp_path / "o")])
        assert res.exit_code != 0 and "/no-such-dr/data/middlebury does not exist" in _said(res.output)
    assert not (tmp_path / "o").exists()


def test_sim_bad_arguments(tmp_path):
    res = CliRunner().invoke(app, ["sim", "--out", str(tmp_path), "--measurements", "0"])
    assert res.exit_code != 0


def test_sim_rejects_bad_quantization(tmp_path):
    with pytest.raises(EvalError, match="quantization"):
        plan_sim(36, quantization=0.0)
    jobs = plan_sim(36, quantization=1.0)
    assert {j.quantization for j in jobs} == {1.0}
