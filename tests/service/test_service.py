"""API tests of the measuring service on a small fake plane source (fast, exact ground truth)."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from fastapi.testclient import TestClient

from factories import SMALL_B, SMALL_H, SMALL_W, WALL_DISP, PlaneSource, wall_frame, wall_length
from measure import Frame
from service.app import create_app
from service_client import BASE, JSON, frame_index, latest, make_client, measure

W, H, BASELINE, DISP = SMALL_W, SMALL_H, SMALL_B, WALL_DISP


def test_measure_on_named_frame_and_history(tmp_path):
    with make_client(tmp_path) as c:
        assert c.get("/api/health").json()["status"] == "ok"
        f = latest(c)
        assert (f["width"], f["height"]) == (W, H) and {"id", "timestamp"} <= f.keys()
        p1, p2 = (60.0, 120.0), (260.0, 150.0)
        r = measure(c, f["id"], p1, p2, method="basic")
        assert r.status_code == 200, r.text
        m = r.json()
        assert m["frame_id"] == f["id"] and m["p1"] == list(p1) and m["method"] == "basic"
        assert m["distance_m"] == pytest.approx(wall_length(p1, p2), rel=1e-6)
        assert {"id", "created", "uncertainty_m", "samples_px", "support", "fit", "warnings"} <= m.keys()
        listed = c.get("/api/measurements").json()
        assert [x["id"] for x in listed] == [m["id"]]
        assert c.get(f"/api/measurements/{m['id']}/thumb.png").content[:8] == b"\x89PNG\r\n\x1a\n"
        png = c.get(f"/api/frames/{f['id']}/color.png")
        assert png.status_code == 200 and png.headers["content-type"] == "image/png"
        disp = c.get(f"/api/frames/{f['id']}/disparity.png")
        assert disp.status_code == 200 and disp.content[:4] == b"\x89PNG"
        import cv2

        img = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(img, wall_frame(frame_index(c, f)).image)  # lossless, that exact frame
        dimg = cv2.imdecode(np.frombuffer(disp.content, np.uint8), cv2.IMREAD_COLOR)
        assert (dimg[:8, :8] == 0).all() and dimg[100, 100].any()  # hole black, data coloured


def test_measurement_uses_exactly_the_named_frame(tmp_path):
    """A frame whose disparity differs from the live ones: the answer must come from it alone."""
    with make_client(tmp_path) as c:
        ring = c.app.state.ring
        base = wall_frame(0)
        near = Frame(base.image, np.full((H, W), 2 * DISP, np.float32), base.camera, BASELINE, meta={"source": "near"})
        entry = ring.push(near, frozen=True)
        latest(c, after=entry.id + 3)  # the stream moved on
        m = measure(c, entry.id, (10, 10), (310, 10), method="basic").json()
        assert m["distance_m"] == pytest.approx(wall_length((10, 10), (310, 10)) / 2, rel=1e-6)


def test_evicted_frame_is_410_and_frozen_survives(tmp_path):
    state = {"gate": threading.Semaphore(0)}  # the test releases frames one by one: no race with eviction
    # keep_viewed=1: of the frames handed out as latest only the last one is kept beyond the ring
    with make_client(tmp_path, factory=lambda: PlaneSource(state=state), ring_size=4, keep_viewed=1) as c:
        state["gate"].release(1)
        old = latest(c)
        state["gate"].release(1)
        kept = latest(c, after=old["id"])
        assert c.post(f"/api/frames/{kept['id']}/freeze", headers=JSON).json()["frozen"] is True
        state["gate"].release(10)
        latest(c, after=kept["id"] + 9)
        r = measure(c, old["id"], (10, 10), (20, 20), method="basic")
        assert r.status_code == 410 and "evicted" in r.json()["detail"]
        assert c.get(f"/api/frames/{old['id']}/color.png").status_code == 410
        assert measure(c, kept["id"], (10, 10), (20, 20), method="basic").status_code == 200
        assert measure(c, 10**9, (10, 10), (20, 20)).status_code == 404
        assert c.delete(f"/api/frames/{kept['id']}/freeze").json()["frozen"] is False
        assert c.get(f"/api/frames/{kept['id']}").status_code == 410  # unfrozen, it was the oldest: evicted


@pytest.mark.parametrize(
    "body, fragment",
    [
        ({"p1": [-1, 10], "p2": [20, 20]}, "outside"),
        ({"p1": [10, 10], "p2": [W, 20]}, "outside"),
        ({"p1": [10, 10], "p2": [20, H + 5]}, "outside"),
        ({"p1": ["10", 10], "p2": [20, 20]}, "p1"),
        ({"p1": [10], "p2": [20, 20]}, "p1"),
        ({"p1": [10, 10], "p2": [20, 20], "frame_id": "abc"}, "frame_id"),
        ({"p1": [10, 10], "p2": [20, 20], "options": {"method": "magic"}}, "method"),
        ({"p1": [10, 10], "p2": [20, 20], "options": {"window": 4}}, None),
        ({"p1": [10, 10], "p2": [20, 20], "options": {"bogus": 1}}, "bogus"),
        ({"p1": [10, 10], "p2": [10, 10]}, "same pixel"),
    ],
)
def test_bad_input_is_422_with_message(tmp_path, body, fragment):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        payload = {"frame_id": fid, **body}
        r = c.post("/api/measure", json=payload)
        assert r.status_code == 422, r.text
        assert isinstance(r.json()["detail"], str) and r.json()["detail"]
        if fragment:
            assert fragment in r.json()["detail"]
        assert c.get("/api/measurements").json() == []


def test_nan_and_infinity_are_422(tmp_path):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        for raw in (
            f'{{"frame_id": {fid}, "p1": [NaN, 10], "p2": [20, 20]}}',
            f'{{"frame_id": {fid}, "p1": [10, 10], "p2": [Infinity, 20]}}',
            "not json at all",
        ):
            r = c.post("/api/measure", content=raw, headers={"content-type": "application/json"})
            assert r.status_code == 422, raw
            json.dumps(r.json(), allow_nan=False)  # the error itself is valid JSON


def test_token_protects_api(tmp_path):
    with make_client(tmp_path, token="s3cret") as c:
        assert c.get("/api/health").status_code == 200  # supervisors need no token
        r = c.get("/api/source")
        assert r.status_code == 401 and "token" in r.json()["detail"]
        assert c.get("/api/source", headers={"Authorization": "Bearer wrong"}).status_code == 401
        assert c.get("/api/source", params={"token": "wrong"}).status_code == 401
        assert c.get("/api/source", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        f = c.get("/api/frames/latest", params={"token": "s3cret", "wait": 5})
        assert f.status_code == 200
        assert c.get("/").status_code == 200  # the page itself is static


def test_restart_keeps_history_and_reopens_frame(tmp_path):
    with make_client(tmp_path) as c:
        f = latest(c)
        first = measure(c, f["id"], (30, 40), (290, 200), method="basic").json()
        second = measure(c, f["id"], (30, 40), (130, 40), method="basic").json()
        gone = measure(c, f["id"], (20, 5), (100, 5), method="basic").json()
        assert c.delete(f"/api/measurements/{gone['id']}").status_code == 200
        assert c.delete(f"/api/measurements/{gone['id']}").status_code == 404
    with make_client(tmp_path) as c:  # a new app on the same database
        listed = c.get("/api/measurements").json()
        assert [m["id"] for m in listed] == [second["id"], first["id"]]
        assert listed[1]["distance_m"] == pytest.approx(first["distance_m"])
        assert listed[1]["p2"] == [290, 200]
        opened = c.post(f"/api/measurements/{first['id']}/open", headers=JSON).json()
        fid = opened["frame"]["id"]
        assert opened["frame"]["frozen"] and opened["measurement"]["id"] == first["id"]
        again = measure(c, fid, (30, 40), (290, 200), method="basic").json()
        assert again["distance_m"] == pytest.approx(first["distance_m"], rel=1e-9)
        rows = list(csv.DictReader(io.StringIO(c.get("/api/measurements.csv").text)))
        assert [int(r["id"]) for r in rows] == [first["id"], second["id"], again["id"]]
        # lengths are rounded to two significant digits of the 1-sigma uncertainty
        assert float(rows[0]["distance"]) == pytest.approx(first["distance_m"], abs=float(rows[0]["uncertainty_1sigma"]) / 10)
        assert c.get("/api/measurements", params={"format": "csv"}).text == c.get("/api/measurements.csv").text
    # the deleted measurement's frame is shared with kept ones, so it stays; one file per frame
    assert len(list((tmp_path / "h-frames").glob("*.frame"))) == 1


def test_disconnecting_source_is_reported_and_retried(tmp_path):
    state = {"refuse": 0}
    seen: set[str] = set()

    def factory():
        return PlaneSource(fail_after=3, state=state)

    with make_client(tmp_path, factory=factory, reconnect_initial_s=0.05) as c:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not {"disconnected", "streaming"} <= seen:
            s = c.get("/api/source").json()
            seen.add(s["state"])
            if s["state"] == "disconnected":
                assert "cable pulled" in s["message"]
            time.sleep(0.005)
        assert {"disconnected", "streaming"} <= seen
        state["refuse"] = 3  # the next reopenings fail too: still no crash, message says so
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            s = c.get("/api/source").json()
            if "unplugged" in s["message"]:
                break
            time.sleep(0.005)
        assert "unplugged" in s["message"] and s["state"] in ("disconnected", "reconnecting")
        start = c.get("/api/source").json()["retries"]
        latest(c, after=latest(c)["id"])  # frames flow again after the retries
        assert c.get("/api/source").json()["retries"] >= start


def test_health_is_degraded_while_the_source_is_down(tmp_path):
    state = {"refuse": 0}
    with make_client(tmp_path, factory=lambda: PlaneSource(fail_after=3, state=state), reconnect_initial_s=0.3, reconnect_max_s=0.3) as c:
        latest(c)
        state["refuse"] = 10**6  # unplugged for good
        deadline = time.monotonic() + 10
        while "unplugged" not in (h := c.get("/api/health").json())["source_message"] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert h["status"] == "degraded" and h["source_state"] in ("disconnected", "reconnecting"), h
        assert any("unplugged" in r for r in h["reasons"]) and "unplugged" in h["reason"]
        state["refuse"] = 0  # plugged back in
        deadline = time.monotonic() + 10
        while (h := c.get("/api/health").json())["source_state"] != "streaming" and time.monotonic() < deadline:
            time.sleep(0.005)
        assert h["status"] == "ok" and h["reasons"] == [], h


def test_source_that_cannot_be_made_fails_once_and_is_not_retried(tmp_path):
    """A spec that makes no source (an unknown kind) is a configuration error: it fails once, is not
    reopened in a loop, and health says why."""
    with TestClient(create_app("nosuchkind:x", db_path=tmp_path / "x.db", reconnect_initial_s=0.02), base_url=BASE) as c:
        deadline = time.monotonic() + 5
        while c.get("/api/source").json()["state"] != "failed" and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)  # ten backoffs: a retrying capture would have reopened meanwhile
        s = c.get("/api/source").json()
        assert s["state"] == "failed" and s["retries"] == 0 and "unknown source kind" in s["message"]
        r = c.get("/api/frames/latest")
        assert r.status_code == 503 and "nosuchkind" in r.json()["detail"]
        h = c.get("/api/health").json()
        assert h["status"] == "degraded" and "unknown source kind" in h["reason"] and h["source_state"] == "failed"


def test_unreadable_calibration_is_not_reopened_in_a_loop(tmp_path):
    """A source whose calibration cannot be read fails with CalibrationError at open: opened once."""
    from device import CalibrationError

    opens = []

    class BadCalibration(PlaneSource):
        def open(self):
            opens.append(1)
            raise CalibrationError(f"{tmp_path / 'calib.yaml'}: not a calibration file (field K missing)")

    with make_client(tmp_path, factory=BadCalibration) as c:
        deadline = time.monotonic() + 5
        while c.get("/api/source").json()["state"] != "failed" and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.3)  # make_client's backoff is 0.02-0.1 s: a retrying capture would reopen meanwhile
        assert len(opens) == 1
        h = c.get("/api/health").json()
        assert h["status"] == "degraded" and "calib.yaml" in h["reason"] and "restart" in h["source_message"]


def test_concurrent_measurements_no_errors(tmp_path):
    """Quick version of bench/bench_service_load.py: 80 measurements from 8 clients on a live stream."""
    with make_client(tmp_path, capture_fps=30.0) as c:
        latest(c)  # the stream is up
        rng = np.random.default_rng(0)
        errors: list[str] = []
        lock = threading.Lock()

        def one(i: int) -> float:
            fid = c.get("/api/frames/latest").json()["id"]
            c.post(f"/api/frames/{fid}/freeze", headers=JSON)
            p1 = (float(rng.uniform(10, 150)), float(rng.uniform(10, 230)))
            p2 = (float(rng.uniform(170, 310)), float(rng.uniform(10, 230)))
            r = measure(c, fid, p1, p2, method="basic")
            if r.status_code != 200:
                with lock:
                    errors.append(r.text)
                return float("nan")
            return abs(r.json()["distance_m"] - wall_length(p1, p2))

        with ThreadPoolExecutor(8) as pool:
            diffs = list(pool.map(one, range(80)))
        assert errors == []
        assert max(diffs) < 1e-6
        assert len(c.get("/api/measurements").json()) == 80


def test_recording_start_stop(tmp_path):
    from device.formats.recording import open_recording

    with make_client(tmp_path, capture_fps=50.0) as c:
        latest(c)
        out = tmp_path / "recordings" / "rec"  # the default root: next to the database
        r = c.post("/api/recordings", json={"action": "start", "out": "rec"})
        assert r.status_code == 200 and r.json()["active"], r.text
        assert c.post("/api/recordings", json={"action": "start"}).status_code == 409
        deadline = time.monotonic() + 10
        while c.get("/api/recordings").json()["frames"] < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
        stopped = c.post("/api/recordings", json={"action": "stop"}).json()
        assert not stopped["active"] and stopped["frames"] >= 5 and stopped["error"] == ""
        assert c.post("/api/recordings", json={"action": "stop"}).status_code == 409
        assert c.post("/api/recordings", json={"action": "pause"}).status_code == 422
        rec = open_recording(out)
        assert len(rec) == stopped["frames"]
        f = rec.frame(len(rec) - 1)
        assert f.meta["source"] == "plane"
        np.testing.assert_array_equal(f.image, wall_frame(f.meta["index"]).image)
        np.testing.assert_allclose(f.disparity[8:, 8:], DISP)


def test_ring_evicts_oldest_live_and_bounds_frozen():
    from service.frames import FrameGone, FrameRing, FrameUnknown

    ring = FrameRing(capacity=3, max_frozen=2)
    ids = [ring.push(wall_frame(i)).id for i in range(3)]
    ring.freeze(ids[0])
    for i in range(5):
        ring.push(wall_frame(10 + i))
    assert ring.get(ids[0]).frozen  # frozen outlives 5 newer frames in a ring of 3
    with pytest.raises(FrameGone, match="evicted"):
        ring.get(ids[1])
    with pytest.raises(FrameUnknown):
        ring.get(999)
    a, b = ring.push(wall_frame(20), frozen=True).id, ring.push(wall_frame(21), frozen=True).id
    assert ring.frozen_ids == [a, b]  # the third frozen frame released the oldest one
    assert len(ring) == 2 + 3


def test_replay_without_loop_ends_instead_of_starting_over(tmp_path):
    from device.formats.recording import RecordingWriter

    with RecordingWriter(tmp_path / "rec", PlaneSource().info) as w:
        for i in range(1, 4):
            w.write(wall_frame(i))
    spec = f"replay:{tmp_path / 'rec'}?realtime=0"
    with TestClient(create_app(spec, db_path=tmp_path / "h.db", capture_fps=200.0, reconnect_initial_s=0.02), base_url=BASE) as c:
        deadline = time.monotonic() + 10
        while c.get("/api/source").json()["state"] != "ended" and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)  # a reopened replay would deliver its frames again within this
        s = c.get("/api/source").json()
        assert s["state"] == "ended" and "reached its end after 3 frames" in s["message"], s
        assert s["frames"] == 3 and s["retries"] == 0
        f = latest(c)  # the last frame stays measurable
        r = measure(c, f["id"], (60.0, 120.0), (260.0, 150.0))
        assert r.status_code == 200 and r.json()["distance_m"] > 0


def test_source_status_states_the_device_depth_processing(tmp_path):
    """/api/source repeats what the source says it does to depth (an OAK's SourceInfo.extra["depth"])."""
    depth = {"postprocessing": "measurement", "temporal_filter": False, "decimation": 1, "hole_filling": False}

    def factory():
        src = PlaneSource()
        src.info = dataclasses.replace(src.info, extra={"depth": depth})
        return src

    with make_client(tmp_path, factory=factory) as c:
        latest(c)
        assert c.get("/api/source").json()["depth"] == depth
    with make_client(tmp_path / "plain") as c:
        latest(c)
        assert c.get("/api/source").json()["depth"] is None
