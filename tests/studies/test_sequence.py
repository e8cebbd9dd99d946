"""Several frames of a still scene (measure.sequence) on the frames study's simulated sequences: pooling gain,
coverage, motion refusal, the study's report (the API side is tests/service/test_service_sequence.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from evaluation.frames_study import FramesJob, run_job, trial_frames
from measure.metrics import accuracy
from measure import MeasureError, MeasureOptions
from measure.sequence import MAX_FRAMES, measure_sequence, static_share, still_frames

SMALL = dict(width=640, height=360)  # a quarter of the pixels: the same geometry, a faster test


@pytest.fixture(scope="module")
def still_trials():
    """Eight still 10-frame scenes of the poster's width at 7 m (fresh noise and contention per frame)."""
    return [trial_frames(FramesJob(7.0, "poster-width", "fresh", 500 + k, **SMALL)) for k in range(8)]


def test_ten_frames_cut_the_spread_at_7m_with_mean_no_worse(still_trials):
    one, ten = [], []
    for frames, truth, clicks in still_trials:
        p1, p2 = clicks["exact"]
        one.append(accuracy(truth.length_m, measure_sequence(frames[-1:], p1, p2).distance_m))
        m = measure_sequence(frames, p1, p2)
        assert m.frames_used == 10 and not any(r.startswith("scene moved") for r in m.reasons)
        ten.append(accuracy(truth.length_m, m.distance_m))
    one, ten = np.array(one), np.array(ten)
    assert np.std(ten, ddof=1) * 2 <= np.std(one, ddof=1), (one, ten)
    assert ten.mean() >= one.mean() - 0.1


def _reduced_study(seed: int) -> list[dict]:
    """Ten still 10-frame scenes at 6 and 7 m (fresh and static contention), both targets, both click kinds."""
    jobs = [FramesJob(d, "poster-width", c, seed * 1000 + 10 * k + i, **SMALL)
            for i, (d, c) in enumerate(((6.0, "fresh"), (7.0, "static"))) for k in range(5)]
    return [r for job in jobs for r in run_job(job)]


@pytest.fixture(scope="module")
def reduced_study():
    return _reduced_study(0)


def _coverage(records, kind, n, key):
    rows = [r for r in records if r["clicks"] == kind and r.get("n") == n and "distance_m" in r]
    assert len(rows) >= 16, len(rows)  # 20 cases: at most a few without an answer
    return float(np.mean([r[key] for r in rows])), rows


@pytest.mark.parametrize("kind", ["exact", "human"])
@pytest.mark.parametrize("n", [1, 10])
def test_pooled_uncertainty_covers_the_truth(reduced_study, kind, n):
    """One sigma (nominal 68 %) and the 95 % interval cover the truth at least as often as claimed, less
    the binomial slack of 20 cases (one sigma >= 45 %, 95 % >= 85 %); seeds 0-4 (`_reduced_study`) gave
    60-100 % / 90-100 % (human clicks at N = 10 the lowest: 60, 75, 75, 80, 80 %)."""
    one, rows = _coverage(reduced_study, kind, n, "covered1")
    ninety_five, _ = _coverage(reduced_study, kind, n, "covered95")
    assert one >= 0.45 and ninety_five >= 0.85, (one, ninety_five)
    # each stated part against its truth: the click error within the click part as a normal error is
    # within one sigma (68 %, here >= 45 % of 20), the sensor error within the rest
    if kind == "human":
        assert np.mean([abs(r["click_err_m"]) <= r["click_sigma_m"] for r in rows]) >= 0.45
    assert np.mean([abs(r["sensor_err_m"]) <= r["sensor_sigma_m"] for r in rows]) >= 0.5


def test_pooling_shrinks_the_sensor_part_not_the_clicks(reduced_study):
    def mean_sigma(kind, n):
        return float(np.mean([r["sigma_m"] / r["truth_m"] for r in reduced_study if r["clicks"] == kind and r.get("n") == n and "sigma_m" in r]))

    # exact clicks: only the sensor's uncertainty, which ten fresh frames cut by more than half
    assert mean_sigma("exact", 10) <= 0.5 * mean_sigma("exact", 1)
    for r in reduced_study:
        if "sigma_m" in r:
            assert r["sigma_m"] <= r["single_sigma_m"] * (1 + 1e-9)  # the mean of still frames never widens
            # human clicks: their error is the same in every frame and stays whole in the sigma
            assert r["sigma_m"] >= r["click_sigma_m"] * (1 - 1e-9)


def test_repeated_frames_are_all_static_and_do_not_shrink_the_sigma(still_trials):
    frames, truth, clicks = still_trials[0]
    p1, p2 = clicks["exact"]
    assert static_share(frames, p1, p2) < 0.3  # fresh noise per frame
    same = [frames[-1]] * 10  # one frame ten times: every error repeats
    assert static_share(same, p1, p2) == pytest.approx(1.0)
    one = measure_sequence(frames[-1:], p1, p2, click_px=0.0)
    ten = measure_sequence(same, p1, p2, click_px=0.0)
    assert ten.distance_m == pytest.approx(one.distance_m, rel=1e-6)
    assert ten.uncertainty_m >= 0.7 * one.uncertainty_m  # nothing was seen to average
    fresh = measure_sequence(frames, p1, p2, click_px=0.0)
    assert fresh.uncertainty_m < 0.7 * one.uncertainty_m


def test_click_px_states_the_clicks_error():
    frames, truth, clicks = trial_frames(FramesJob(6.0, "poster-width", "fresh", 41, **SMALL), n=3)
    p1, p2 = clicks["human"]
    default = measure_sequence(frames[-1:], p1, p2)
    exact = measure_sequence(frames[-1:], p1, p2, click_px=0.0)
    wide = measure_sequence(frames[-1:], p1, p2, click_px=6.0)
    assert exact.uncertainty_m < default.uncertainty_m < wide.uncertainty_m
    assert exact.distance_m == default.distance_m == wide.distance_m
    for bad in (-1.0, math.nan, 1e3, True):
        with pytest.raises(MeasureError, match="click_px"):
            measure_sequence(frames, p1, p2, click_px=bad)


def test_a_pooled_model_most_frames_do_not_show_falls_back_to_per_frame_fits():
    # 2 m, static contention: the repeated wrong matches at the board's edge, counted ten times, make the
    # pooled fit see a surface of its own at an end (956 mm against 838 true); no single frame does.
    job = FramesJob(2.0, "poster-width", "static", 10002)
    frames, _, _ = trial_frames(job, 10)
    from evaluation.frames_study import TARGETS, _clicks, _params
    from sim.scenes import get_view

    truth = get_view(_params(job, 9, 10)).truth("poster-width")
    p1, p2 = _clicks(truth, job, TARGETS.index("poster-width"))["exact"]
    m = measure_sequence(frames, p1, p2, click_px=0.0)
    assert m.frames_used == 10 and any("per-frame fits combined" in w for w in m.warnings), m.warnings
    assert abs(m.distance_m - truth.length_m) < 0.005
    lo, hi = m.interval_m
    assert lo <= truth.length_m <= hi


@pytest.mark.parametrize("motion", ["pan", "push"])
def test_moving_camera_is_refused(motion):
    frames, truth, clicks = trial_frames(FramesJob(7.0, "poster-width", "fresh", 900, motion=motion, **SMALL))
    p1, p2 = clicks["exact"]
    m = measure_sequence(frames, p1, p2)
    assert m.frames_used == 1
    assert any(r.startswith("scene moved") and "1 of 10 frames pooled" in r for r in m.reasons), m.reasons
    assert m.quality != "good"  # a scene-moved reason demotes the answer
    single = measure_sequence(frames[-1:], p1, p2)
    assert m.distance_m == pytest.approx(single.distance_m) and m.uncertainty_m == pytest.approx(single.uncertainty_m)


def test_a_move_that_ended_keeps_the_still_frames_after_it():
    moved, _, _ = trial_frames(FramesJob(7.3, "poster-width", "fresh", 901, **SMALL), n=4)
    still, truth, clicks = trial_frames(FramesJob(7.0, "poster-width", "fresh", 902, **SMALL), n=6)
    p1, p2 = clicks["exact"]
    assert still_frames(moved + still, p1, p2)[0] == 6
    m = measure_sequence(moved + still, p1, p2)
    assert m.frames_used == 6 and any("6 of 10 frames pooled" in r for r in m.reasons), m.reasons
    assert m.distance_m == pytest.approx(measure_sequence(still, p1, p2).distance_m)


def test_static_contention_repeats_and_fresh_does_not():
    a, _, clicks = trial_frames(FramesJob(4.0, "poster-width", "static", 7, **SMALL), n=2)
    b, _, _ = trial_frames(FramesJob(4.0, "poster-width", "fresh", 7, **SMALL), n=2)
    big = lambda f, g: np.nan_to_num(np.abs(f.disparity - g.disparity)) > 1.5  # noqa: E731 — a wrong match moves 2-8 px
    # fresh contention: outliers in different places frame to frame; static: only where noise/holes differ
    assert big(a[0], a[1]).sum() * 5 < big(b[0], b[1]).sum()


def test_bad_sequences_raise():
    frames, _, clicks = trial_frames(FramesJob(4.0, "poster-width", "fresh", 3, **SMALL), n=2)
    p1, p2 = clicks["exact"]
    with pytest.raises(MeasureError, match="no frames"):
        measure_sequence([], p1, p2)
    with pytest.raises(MeasureError, match="at most"):
        measure_sequence(frames * (MAX_FRAMES // 2 + 1), p1, p2)
    with pytest.raises(MeasureError, match="robust"):
        measure_sequence(frames, p1, p2, MeasureOptions(method="basic"))
    other = replace(frames[0], baseline_m=frames[0].baseline_m * 2)
    with pytest.raises(MeasureError, match="another camera"):
        measure_sequence([other, frames[1]], p1, p2)


def test_frames_study_writes_table_and_plot(tmp_path):
    from evaluation.frames_study import run, summarize, wilson, write_report

    jobs = [FramesJob(3.5, "poster-width", "static", 11, **SMALL), FramesJob(3.5, "poster-width", "fresh", 12, motion="pan", **SMALL)]
    records = run(jobs)
    paths = write_report(tmp_path, records, {"trials": 1, "near_trials": 1})
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = paths["report"].read_text()
    assert "| 2-5 m | static | exact | 10 | 2 (1) |" in text and "2 of 2 moving 10-frame cases (1 sequences x 2 click kinds) refused" in text
    cell = summarize(records)["cells"]["2-5 m|static|exact|10"]
    assert cell["n"] == 2 and cell["frames_used"] == 10 and cell["mean_A"] > 99.0
    lo, hi = wilson(95, 100)
    assert lo == pytest.approx(0.888, abs=1e-3) and hi == pytest.approx(0.978, abs=1e-3)
