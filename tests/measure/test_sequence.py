"""Several frames of a still scene (measure.sequence, issue #17): pooling gain, coverage, motion refusal, API."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from evaluation.frames_study import FramesJob, trial_frames
from evaluation.report import accuracy
from measure import MeasureError, MeasureOptions
from measure.sequence import MAX_FRAMES, measure_sequence, still_frames

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


@pytest.mark.parametrize("kind", ["exact", "human"])
def test_pooled_interval_covers_the_truth_and_never_widens(still_trials, kind):
    covered = 0
    for frames, truth, clicks in still_trials:
        p1, p2 = clicks[kind]
        for n in (3, 10):
            m = measure_sequence(frames[-n:], p1, p2)
            lo, hi = m.interval_m
            covered += lo <= truth.length_m <= hi
            # what pooling removes is only the part seen to vary from frame to frame
            assert m.uncertainty_m <= m.single_frame_uncertainty_m * (1 + 1e-9)
            assert m.uncertainty_m >= 0.3 * m.single_frame_uncertainty_m  # the clicks' share stays
    assert covered >= 0.9 * 2 * len(still_trials)  # the 95 % interval, on 16 answers


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


def test_api_measures_over_frames_held_since_the_freeze(tmp_path):
    from fastapi.testclient import TestClient

    from service.app import create_app

    spec = "sim:poster?distance=6&width=640&height=360&fps=0&seed=4"
    with TestClient(create_app(spec, db_path=tmp_path / "h.db", ring_size=12, capture_fps=100.0), base_url="http://127.0.0.1") as c:
        ring = c.app.state.ring
        first = ring.wait_latest(0, 20.0)
        assert first is not None
        fid = ring.wait_latest(first.id + 11, 60.0).id  # at least 11 frames from the source
        assert c.post(f"/api/frames/{fid}/freeze", json={}).json()["frozen"] is True
        ring.wait_latest(fid + 16, 60.0)  # the stream moved on past the ring's 12 frames
        truth = ring.get(fid).frame.meta["truth"]
        body = {"frame_id": fid, "p1": list(map(float, truth.p1_px)), "p2": list(map(float, truth.p2_px))}
        one = c.post("/api/measure", json=body)
        ten = c.post("/api/measure", json={**body, "frames": 10})
        assert one.status_code == 200 and ten.status_code == 200, (one.text, ten.text)
        one, ten = one.json(), ten.json()
        assert one["frames_used"] == 1 and "frame_ids" not in one
        assert ten["frames_used"] == 10, ten["reasons"]
        assert ten["frame_ids"] == list(range(fid - 9, fid + 1))
        assert ten["frames_requested"] == 10 and ten["single_frame_uncertainty_m"] == pytest.approx(one["uncertainty_m"])
        assert abs(ten["distance_m"] - truth.length_m) < ten["interval_m"][1] - ten["distance_m"]
        stored = c.get(f"/api/measurements/{ten['id']}").json()
        assert stored["frame_ids"] == ten["frame_ids"] and stored["frames_used"] == 10
        assert c.post("/api/measure", json={**body, "frames": 31}).status_code == 422
        bad = c.post("/api/measure", json={**body, "frames": 3, "options": {"method": "basic"}})
        assert bad.status_code == 422 and "robust" in bad.json()["detail"]


def test_frames_study_writes_table_and_plot(tmp_path):
    from evaluation.frames_study import run, summarize, write_report

    jobs = [FramesJob(4.0, "poster-width", "static", 11, **SMALL), FramesJob(4.0, "poster-width", "fresh", 12, motion="pan", **SMALL)]
    records = run(jobs)
    paths = write_report(tmp_path, records, {"trials": 1})
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = paths["report"].read_text()
    assert "| 4 m | 10 | samples |" in text and "2 of 2 moving 10-frame cases (1 sequences x 2 click kinds) refused" in text
    cell = summarize(records)["cells"]["static|exact|4 m|10|samples"]
    assert cell["n"] == 1 and cell["frames_used"] == 10 and cell["mean_A"] > 99.0
