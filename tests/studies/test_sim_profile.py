"""The simulator's ``paper`` profile: its sensor effects, and the paper's relative findings
on a reduced study (the full 1800-measurement figures are in docs/eval/sim-paper/)."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from device import SourceError, open_source
from evaluation.paper_figures import paper_beside_ours
from evaluation.report import EvalError
from evaluation.sim_study import plan_sim, run_sim, summarize_sim
from sim.scenario import make_model
from sim.scenes import SceneParams, get_view
from sim.sensor import SensorModel, get_profile, sense

QUIET = dict(noise_px=0.0, contention=0.0, quantization=0.0, hole_fraction=0.0, stray_hole_fraction=0.0,
             stray_outlier_fraction=0.0, edge_fattening_px=0)


def test_profiles_set_sensor_clicks_and_mount():
    stress, paper = make_model("indoor"), make_model("indoor", "paper")
    assert stress == SensorModel()
    assert paper.quantization == 1.0 and paper.outlier_model == "other-surface" and paper.contention == 0.5
    assert make_model("indoor", "paper", quantization=None, noise_px=0.1).quantization == 1.0  # None = the profile's
    assert get_profile("paper").mount == "wall" and get_profile("stress").mount == "stand"
    clicks = get_profile("paper").clicks  # "one or a few pixels away": the scatter, without extra off-object taps
    assert clicks.jitter_px == sim.ClickModel().jitter_px and clicks.off_object_prob == 0.0
    with pytest.raises(sim.SensorError, match="stress, paper"):
        make_model("indoor", "tablet")
    frame, _, _ = sim.scenario("poster", profile="paper", distance_m=6.0, seed=2, width=640, height=360)
    d = frame.disparity[np.isfinite(frame.disparity)]
    np.testing.assert_array_equal(d, np.round(d))  # integer disparity (the paper's Fig. 3)


def test_noise_is_correlated_over_the_matching_window():
    view = get_view(SceneParams("poster", 2.0, mount="wall", width=640, height=360))
    for window, lo, hi in ((0, -0.1, 0.1), (9, 0.45, 0.95)):
        model = SensorModel(**{**QUIET, "noise_px": 0.3, "noise_window_px": window})
        err = sense(view, model, np.random.default_rng(4)).disparity - view.camera.fx * model.baseline_wide_m / view.depth
        board = err[120:240, 240:400]  # the textured poster, away from its outline
        assert abs(board.std() - 0.3) < 0.05  # the window keeps the noise's standard deviation
        # Correlation of errors 4 px apart along a row (2 aux pixels: beyond one aux block).
        corr = np.corrcoef(board[:, :-4].ravel(), board[:, 4:].ravel())[0, 1]
        assert lo < corr < hi, (window, corr)


def test_paper_contention_takes_the_other_surface_where_the_pairs_disagree():
    view = get_view(SceneParams("boxes", 2.0, width=640, height=360))
    model = SensorModel(**{**QUIET, "contention": 0.5, "contention_at": "disagreement", "contention_band_px": 4,
                           "contention_area": 0.0, "contention_low_texture": 0.0, "outlier_model": "other-surface"})
    out = sense(view, model, np.random.default_rng(5))
    st = out.static
    assert out.outlier.sum() > 500
    # An outlier is the surface across the edge (a bounded error), never a value from nowhere.
    np.testing.assert_allclose(out.disparity[out.outlier], st.d_other[out.outlier], atol=1e-4)
    step = np.abs(st.d_other - st.d_true)[out.outlier]
    assert np.median(step) > 1.0 and step.max() <= np.nanmax(st.d_true) - np.nanmin(st.d_true)
    # Contended only near a strip that one aux camera sees and the other does not; far fewer pixels
    # than the stress profile's band around every depth edge.
    stress = sense(view, SensorModel(**{**QUIET, "contention": 0.5}), np.random.default_rng(5)).static
    assert st.contended.sum() < 0.5 * stress.contended.sum()


def test_sim_source_accepts_the_profile():
    with open_source("sim:poster?profile=paper&distance=4&fps=0&width=640&height=360") as src:
        frame = src.read()
        assert src.info.extra["profile"] == "paper"
    d = frame.disparity[np.isfinite(frame.disparity)]
    np.testing.assert_array_equal(d, np.round(d))
    with pytest.raises(SourceError, match="stress, paper"):
        open_source("sim:poster?profile=tablet")
    with pytest.raises(EvalError, match="profile"):
        plan_sim(36, profile="tablet")


# The reduced study: the poster's six measurements (width and length, three places each) square-on at 2
# and 7 m under three lightings, from the 588-measurement plan: 108 measurements on 2 views. Checked on
# seeds 0-9: paper - basic +2.4 to +4.3 overall, +4.5 to +8.3 at 7 m against -0.1 to +0.3 at 2 m, basic
# 91.3-93.7, false gaps 13-25 % (a poster only; about 11 % over the full study), the standard deviation
# of A 3.5 to 5.9 points lower (the paper: 5 points, "a 5% reduction"; evaluation/paper_figures.py),
# z_only's gain within 0.4 of paper's. The false gaps' share at >= 6 m needs the full study.
REDUCED_N = 588


@pytest.fixture(scope="module")
def reduced() -> dict:
    jobs = [j for j in plan_sim(REDUCED_N, seed=7, gap_fraction=0.0, profile="paper")
            if j.scene == "poster" and j.yaw_deg == 0.0 and j.distance_m in (2.0, 7.0)]
    assert len(jobs) == 108
    return summarize_sim(run_sim(jobs, workers=1))


def _gain(r: dict, key: str | None = None) -> float:
    ma, mb = r["methods"]["paper"], r["methods"]["basic"]
    if key is None:
        return ma["overall"]["mean"] - mb["overall"]["mean"]
    return ma["by_distance"][key]["mean"] - mb["by_distance"][key]["mean"]


@pytest.mark.slow
def test_paper_profile_holds_the_papers_relative_findings(reduced):
    r = reduced
    assert 0.5 < _gain(r) < 6.0  # the paper: +2.6 (here a poster only, square-on, at 2 and 7 m)
    assert _gain(r, "7") > _gain(r, "2") + 1.0  # "the accuracy improvement ... increases as the distance increases"
    assert abs(_gain(r, "2")) < 1.0
    assert 88.0 < r["methods"]["basic"]["overall"]["mean"] < 97.0  # mild end points: not the stress profile's 46
    drop = r["methods"]["basic"]["overall"]["std"] - r["methods"]["paper"]["overall"]["std"]
    assert 0.0 < drop < 12.0  # points of A; "improve both the accuracy and consistency"
    assert 0.03 < r["gap"]["false_positive_rate"] < 0.3  # the paper: 6.8 %


@pytest.mark.slow
def test_report_puts_the_papers_figures_beside_ours(reduced):
    rows = {row[0]: row[1:] for row in paper_beside_ours(reduced)}
    assert rows["paper − basic, all (points)"] == ["+2.6", f"{_gain(reduced):+.2f}"]
    assert rows["z_only − basic, all (points)"][0] == "+0.6"
    bs, ps = (reduced["methods"][m]["overall"]["std"] for m in ("basic", "paper"))
    assert rows["std of A, paper vs basic (overall)"] == ["−5 points (\"5% reduction\")", f"{ps - bs:+.2f} points ({100 * (ps - bs) / bs:+.1f} % of basic's)"]
    assert rows["std drop per point of mean gain"] == ["1.9 (5 / 2.6)", f"{(bs - ps) / _gain(reduced):.1f}"]
    fp = reduced["gap"]["false_positive_rate"]
    assert rows["gap false positives (paper method)"] == ["6.8 % of 1873", f"{100 * fp:.1f} % of {reduced['gap']['n_non_gap']}"]
    assert rows["robust (default), mean ± std"][1].startswith(f"{reduced['methods']['robust']['overall']['mean']:.2f}")


@pytest.mark.slow
def test_z_only_gains_as_much_as_paper_on_a_straight_target(reduced):
    # Not the paper's +0.6 (docs/decisions/z-only-reading.md): on a flat poster the gain is in
    # the end points' depths, which the robust depth line corrects as well as the 3D line. Seeds 0-9:
    # the two gains differ by -0.03 to +0.38 points.
    z = reduced["methods"]["z_only"]["overall"]["mean"] - reduced["methods"]["basic"]["overall"]["mean"]
    assert abs(z - _gain(reduced)) < 1.5


def test_paper_method_on_a_segment_over_two_pixel_rows_keeps_both_halves():
    """A near-horizontal click pair steps from row 360 to 359: FAST-MCD's exact fit is the plane of one
    row's viewing rays, and the line inside it must use the samples of both rows (it used one row's
    half, at two disparity levels, and ran along Z: 0.203 m for 0.836 m)."""
    import sim
    from measure import MeasureOptions, measure_distance

    frame, truth, (c1, c2) = sim.scenario("poster", target="poster-width", distance_m=4.0, lighting="outdoor", seed=5044,
                                          yaw_deg=0.0, roll_deg=0.0, profile="paper", width=1280, height=720)
    assert round(c1[1]) != round(c2[1])
    m = measure_distance(frame, c1, c2, MeasureOptions(method="paper"))
    assert abs(m.distance_m - truth.length_m) / truth.length_m < 0.15
