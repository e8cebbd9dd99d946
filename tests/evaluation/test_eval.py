"""The evaluation package: protocol, statistics, outlier model, bad arguments (the paper's targets on
reduced runs are tests/studies/test_eval_targets.py)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.eval import app
from evaluation.middlebury import ContentionModel, contended_disparity, contended_regions
from evaluation.sim_study import DISTANCES_M, LIGHTINGS, MEASUREMENT_SET, dimension, plan_sim
from evaluation.report import EvalError, summary
from measure.metrics import accuracy



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
