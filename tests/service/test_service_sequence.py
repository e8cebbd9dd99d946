"""POST /api/measure with ``frames``: a measurement pooled over the frames the ring held up to the
frozen one (measure.sequence through the API), refused beyond the ring or for another method."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from service.app import create_app


def test_api_measures_over_frames_held_since_the_freeze(tmp_path):
    spec = "sim:poster?distance=6&width=640&height=360&fps=0&seed=4"
    # 30 frames in the ring: the 10 before the frozen one must still be there when the freeze lands,
    # however many frames a loaded host lets the source add between wait_latest and the POST
    with TestClient(create_app(spec, db_path=tmp_path / "h.db", ring_size=30, capture_fps=100.0), base_url="http://127.0.0.1") as c:
        ring = c.app.state.ring
        first = ring.wait_latest(0, 20.0)
        assert first is not None
        fid = ring.wait_latest(first.id + 11, 60.0).id  # at least 11 frames from the source
        assert c.post(f"/api/frames/{fid}/freeze", json={}).json()["frozen"] is True
        ring.wait_latest(fid + 34, 60.0)  # the stream moved on past the ring's 30 frames
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
