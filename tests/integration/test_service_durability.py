"""The service under faults: SIGKILL under load, a full disk, stale temporary files, a corrupt replayed
frame, a source that times out once, and a capped history. Nothing acknowledged may be lost."""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from server_process import start_serve
from factories import SMALL_H, SMALL_W, WALL_DISP, PlaneSource, wall_frame, wall_length
from service_client import BASE, JSON, frame_index, latest, make_client, measure

from device import SourceTimeout

SIM = "sim:poster?width=320&height=240&fps=30"


def _serve(db: Path, log: Path, prefix: tuple[str, ...] = (), extra: tuple[str, ...] = ()) -> tuple[subprocess.Popen, str]:
    return start_serve(SIM, db, log, *extra, prefix=prefix, timeout_s=120)


def _points(frame: dict, k: int) -> tuple[list[float], list[float]]:
    t = frame["truth"]
    a, b = np.array(t["p1_px"]), np.array(t["p2_px"])
    u = 0.1 + 0.02 * (k % 10)
    return (a + (b - a) * u).tolist(), (a + (b - a) * (1 - u)).tolist()


@pytest.mark.slow
def test_sigkill_under_load_loses_no_acknowledged_measurement(tmp_path):
    db = tmp_path / "h.db"
    proc, base = _serve(db, tmp_path / "serve.log")
    acked: list[dict] = []
    lock = threading.Lock()
    stop = threading.Event()

    def client(k: int) -> None:
        with httpx.Client(base_url=base, timeout=30, headers=JSON) as http:
            n = 0
            while not stop.is_set():
                try:
                    f = http.get("/api/frames/latest").json()
                    for j in range(2 if k % 2 else 1):  # new frames, and two clicks on one frame
                        p1, p2 = _points(f, n + j)
                        r = http.post("/api/measure", json={"frame_id": f["id"], "p1": p1, "p2": p2, "options": {"method": "basic"}})
                        if r.status_code == 200:
                            with lock:
                                acked.append(r.json())
                    n += 1
                except httpx.TransportError:
                    return  # the server died under us: what it acknowledged must be there

    threads = [threading.Thread(target=client, args=(k,)) for k in range(4)]
    try:
        for t in threads:
            t.start()
        deadline = time.monotonic() + 120
        def enough() -> bool:  # the kill must land while several saved frames and many measurements exist
            with lock:
                return len(acked) >= 40 and len({m["frame_uid"] for m in acked}) >= 3

        while not enough() and time.monotonic() < deadline:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
        stop.set()
        for t in threads:
            t.join(60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert len(acked) >= 40
    assert len({m["frame_uid"] for m in acked}) >= 3
    proc, base = _serve(db, tmp_path / "serve2.log")
    try:
        with httpx.Client(base_url=base, timeout=30, headers=JSON) as http:
            for m in acked:
                got = http.get(f"/api/measurements/{m['id']}")
                assert got.status_code == 200, got.text
                assert got.json()["distance_m"] == m["distance_m"]
                opened = http.post(f"/api/measurements/{m['id']}/open")
                assert opened.status_code == 200, (m["id"], opened.text)
                again = http.post(
                    "/api/measure",
                    json={"frame_id": opened.json()["frame"]["id"], "p1": m["p1"], "p2": m["p2"], "options": {"method": "basic"}},
                )
                assert again.status_code == 200
                # the saved disparity is exact to its 1/64 px step: the length agrees to well under a millimetre
                assert again.json()["distance_m"] == pytest.approx(m["distance_m"], abs=5e-4)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_full_disk_is_507_degraded_and_recovers(tmp_path, monkeypatch):
    from history import frame_file

    with make_client(tmp_path) as c:
        f = latest(c)
        ok = measure(c, f["id"], (10, 10), (200, 10), method="basic")
        assert ok.status_code == 200
        real = frame_file.write_durably
        monkeypatch.setattr(frame_file, "write_durably", _enospc)
        f2 = latest(c, after=f["id"])
        assert c.post(f"/api/frames/{f2['id']}/freeze", headers=JSON).status_code == 200
        r = measure(c, f2["id"], (10, 10), (200, 10), method="basic")
        assert r.status_code == 507, r.text
        assert "full" in r.json()["detail"] and str(tmp_path) in r.json()["detail"]
        h = c.get("/api/health").json()
        assert h["status"] == "degraded" and "full" in h["reason"]
        assert [m["id"] for m in c.get("/api/measurements").json()] == [ok.json()["id"]]  # nothing half-stored
        monkeypatch.setattr(frame_file, "write_durably", real)
        deadline = time.monotonic() + 10  # space is back: health recovers by itself (a probe write twice a second)
        while c.get("/api/health").json()["status"] != "ok" and time.monotonic() < deadline:
            time.sleep(0.05)
        h = c.get("/api/health").json()
        assert (h["status"], h["reason"], h["reasons"], h["source_state"]) == ("ok", "", [], "streaming")
        frame_bytes = next((tmp_path / "h-frames").glob("*.frame")).stat().st_size
        assert h["next_frame_bytes"] == frame_bytes and h["free_bytes"] > frame_bytes
        r = measure(c, f2["id"], (10, 10), (200, 10), method="basic")
        assert r.status_code == 200
        assert c.post(f"/api/measurements/{r.json()['id']}/open", headers=JSON).status_code == 200


@pytest.fixture
def small_disk(tmp_path):
    """A 4 MB tmpfs at ``tmp_path / "disk"`` (root can mount one; skipped with the reason elsewhere)."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command to make a small tmpfs")
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(disk)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a 4 MB tmpfs here (needs root): {mounted.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _fill(disk: Path) -> Path:
    ballast = disk / "ballast"
    with open(ballast, "wb", buffering=0) as fh:
        try:
            while True:
                fh.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
    return ballast


@pytest.mark.slow
def test_full_tmpfs_measure_507_edits_succeed_health_degraded_across_a_restart(tmp_path, small_disk):
    db = small_disk / "h.db"
    extra = ("--recordings", str(tmp_path / "rec"))
    proc, base = _serve(db, tmp_path / "serve.log", extra=extra)
    try:
        with httpx.Client(base_url=base, timeout=30, headers=JSON) as http:
            f = http.get("/api/frames/latest").json()
            p1, p2 = _points(f, 0)
            body = {"frame_id": f["id"], "p1": p1, "p2": p2}  # the default method answers through a dropped click
            first = http.post("/api/measure", json=body)
            assert first.status_code == 200, first.text
            h = http.get("/api/health").json()
            assert h["status"] == "ok" and h["next_frame_bytes"] > 0, h
            ballast = _fill(small_disk)
            h = http.get("/api/health").json()  # no write has failed yet: the free bytes say it
            assert h["status"] == "degraded" and h["free_bytes"] < h["next_frame_bytes"], {k: h[k] for k in ("free_bytes", "next_frame_bytes", "reason")}
            codes = []
            for _ in range(3):
                f = http.get("/api/frames/latest", params={"after": f["id"], "wait": 5}).json()
                codes.append(http.post("/api/measure", json={**body, "frame_id": f["id"]}).status_code)
                assert http.get("/api/health").json()["status"] == "degraded"
            assert codes == [507, 507, 507], codes
            mid = first.json()["id"]
            assert http.patch(f"/api/measurements/{mid}", json={"name": "kept", "note": "on a full disk"}).status_code == 200
            assert http.post(f"/api/measurements/{mid}/pin").json()["pinned"] is True
            assert http.delete(f"/api/measurements/{mid}/pin").json()["pinned"] is False
            assert [m["id"] for m in http.get("/api/measurements").json()] == [mid]  # the 507s left no row
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
        proc, base = _serve(db, tmp_path / "serve2.log", extra=extra)  # restarted on the full disk
        with httpx.Client(base_url=base, timeout=30, headers=JSON) as http:
            h = http.get("/api/health").json()
            assert h["status"] == "degraded" and "next frame needs" in h["reason"], {k: h[k] for k in ("free_bytes", "next_frame_bytes", "reason")}
            assert http.get(f"/api/measurements/{mid}").json()["name"] == "kept"
            assert http.delete(f"/api/measurements/{mid}").status_code == 200  # deleting is how space is freed
            assert http.get("/api/measurements").json() == []
            ballast.unlink()
            deadline = time.monotonic() + 10
            while http.get("/api/health").json()["status"] != "ok" and time.monotonic() < deadline:
                time.sleep(0.1)
            assert http.get("/api/health").json()["status"] == "ok"
            f = http.get("/api/frames/latest").json()
            r = http.post("/api/measure", json={**body, "frame_id": f["id"]})
            assert r.status_code == 200, r.text
            assert http.post(f"/api/measurements/{r.json()['id']}/open").status_code == 200
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)


def _leave(disk: Path, ballast: Path, nbytes: int) -> int:
    """Shorten ``ballast`` (the file that filled ``disk``) until about ``nbytes`` are free; the free bytes."""
    from history.space import free_bytes

    os.truncate(ballast, max(0, ballast.stat().st_size - max(0, nbytes - free_bytes(disk))))
    return free_bytes(disk)


@pytest.mark.slow
def test_tmpfs_with_less_room_than_a_frame_is_degraded_before_a_write_fails(tmp_path, small_disk):
    """Room for a small fixed probe but not for a frame (the case a 64 KB probe called "ok" while three
    measurements got 507): health is degraded before the first measurement fails and after each 507;
    with room for a frame and its commit, health is ok again and the measurement is stored."""
    from history.space import COMMIT_HEADROOM

    proc, base = start_serve("sim:poster?width=640&height=480&fps=30", small_disk / "h.db", tmp_path / "serve.log", timeout_s=120)
    try:
        with httpx.Client(base_url=base, timeout=30, headers=JSON) as http:
            f = http.get("/api/frames/latest").json()
            p1, p2 = _points(f, 0)
            body = {"frame_id": f["id"], "p1": p1, "p2": p2}
            first = http.post("/api/measure", json=body)
            assert first.status_code == 200, first.text
            h = http.get("/api/health").json()
            need = h["next_frame_bytes"]
            assert h["status"] == "ok" and 250_000 < need < 450_000, h  # 640x480: JPEG colour + PNG16 disparity
            assert (small_disk / "h-frames" / ".reserve").exists()  # laid while there was room
            ballast = _fill(small_disk)
            free = _leave(small_disk, ballast, need // 2)
            assert need // 3 < free < need, (free, need)
            h = http.get("/api/health").json()  # no write has failed yet
            assert h["status"] == "degraded" and h["free_bytes"] < h["next_frame_bytes"] == need, h
            codes = []
            for _ in range(2):
                f = http.get("/api/frames/latest", params={"after": f["id"], "wait": 5}).json()
                codes.append(http.post("/api/measure", json={**body, "frame_id": f["id"]}).status_code)
                h = http.get("/api/health").json()
                assert h["status"] == "degraded" and h["free_bytes"] < need, h
            assert codes == [507, 507]
            assert [m["id"] for m in http.get("/api/measurements").json()] == [first.json()["id"]]
            free = _leave(small_disk, ballast, need + COMMIT_HEADROOM + (512 << 10))
            deadline = time.monotonic() + 10  # a failed write is forgotten once a probe of a frame's size writes
            while http.get("/api/health").json()["status"] != "ok" and time.monotonic() < deadline:
                time.sleep(0.1)
            h = http.get("/api/health").json()
            assert h["status"] == "ok" and h["free_bytes"] >= h["next_frame_bytes"] + COMMIT_HEADROOM, h
            f = http.get("/api/frames/latest", params={"after": f["id"], "wait": 5}).json()
            r = http.post("/api/measure", json={**body, "frame_id": f["id"]})
            assert r.status_code == 200, r.text
            assert [m["id"] for m in http.get("/api/measurements").json()] == [r.json()["id"], first.json()["id"]]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)


def test_stale_temporary_files_are_cleaned_at_start(tmp_path):
    frames = tmp_path / "h-frames"
    frames.mkdir()
    stale = [frames / "0123.tmp.npz", frames / ".abcd.frame.tmp", frames / "ffff.frame.tmp"]
    for p in stale:
        p.write_bytes(b"half a frame")
    with make_client(tmp_path) as c:
        f = latest(c)
        assert measure(c, f["id"], (10, 10), (200, 10), method="basic").status_code == 200
    assert not any(p.exists() for p in stale)
    assert len(list(frames.glob("*.frame"))) == 1  # the one measured frame
    assert {p.name for p in frames.iterdir()} <= {p.name for p in frames.glob("*.frame")} | {".reserve"}


def test_frame_is_durable_when_the_measurement_answers(tmp_path):
    """No background queue: the frame file exists, fsync'd, by the time the 200 arrives; it is compact
    (PNG16 disparity + JPEG colour) and reopens with the disparity exact to its 1/64 px step."""
    with make_client(tmp_path) as c:
        f = latest(c)
        m = measure(c, f["id"], (10, 10), (300, 200), method="basic").json()
        files = list((tmp_path / "h-frames").glob("*.frame"))
        assert len(files) == 1 and files[0].stat().st_size < 0.25 * (SMALL_W * SMALL_H * 7)  # 3 B colour + 4 B disparity raw
        from history.store import load_frame

        saved = load_frame(files[0])
        want = wall_frame(frame_index(c, f))
        np.testing.assert_array_equal(np.isnan(saved.disparity), np.isnan(want.disparity))
        np.testing.assert_allclose(saved.disparity[8:, 8:], WALL_DISP, atol=1 / 128)
        assert np.abs(saved.image.astype(int) - want.image.astype(int)).mean() < 2.0  # JPEG, visually lossless
        assert saved.camera == want.camera and saved.baseline_m == want.baseline_m
        assert m["distance_m"] == pytest.approx(wall_length((10, 10), (300, 200)), rel=1e-6)


def test_source_timeout_is_retried_not_reopened(tmp_path):
    opens = []

    class Flaky(PlaneSource):
        def open(self):
            opens.append(1)
            super().open()

        def read(self, timeout_s=1.0):
            if self.n in (3, 4):
                self.n += 1
                raise SourceTimeout("fake plane: no frame within the timeout")
            return super().read(timeout_s)

    with make_client(tmp_path, factory=Flaky) as c:
        latest(c, after=10)
        s = c.get("/api/source").json()
        assert len(opens) == 1 and s["retries"] == 0 and s["state"] == "streaming"
        assert s["timeouts"] == 2


def test_replay_with_a_corrupt_frame_skips_it_and_ends(tmp_path):
    from fastapi.testclient import TestClient

    from device.formats.recording import RecordingWriter
    from service.app import create_app

    with RecordingWriter(tmp_path / "rec", PlaneSource().info) as w:
        for i in range(1, 6):
            w.write(wall_frame(i))
    (tmp_path / "rec" / "color" / "000002.png").write_bytes(b"not a png")
    spec = f"replay:{tmp_path / 'rec'}?realtime=0"
    app = create_app(spec, db_path=tmp_path / "h.db", capture_fps=200.0, reconnect_initial_s=0.02)
    with TestClient(app, base_url=BASE) as c:
        deadline = time.monotonic() + 10
        while c.get("/api/source").json()["state"] != "ended" and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)
        s = c.get("/api/source").json()
        assert s["state"] == "ended" and s["frames"] == 4 and s["retries"] == 0, s
        assert len(s["warnings"]) == 1 and "000002.png" in s["warnings"][0] and "skipped" in s["warnings"][0]


def test_history_cap_drops_oldest_unpinned_frames(tmp_path):
    state = {"gate": threading.Semaphore(0)}
    with make_client(tmp_path, factory=lambda: PlaneSource(state=state), history_max_bytes=1) as c:
        ids = []
        after = 0
        for _ in range(4):
            state["gate"].release(1)
            f = latest(c, after=after)
            after = f["id"]
            ids.append(measure(c, f["id"], (10, 10), (200, 10), method="basic").json()["id"])
            if len(ids) == 1:
                assert c.post(f"/api/measurements/{ids[0]}/pin", headers=JSON).json()["pinned"] is True
        # a cap below one frame keeps the newest frame and the pinned one
        assert c.post(f"/api/measurements/{ids[0]}/open", headers=JSON).status_code == 200
        assert c.post(f"/api/measurements/{ids[3]}/open", headers=JSON).status_code == 200
        for mid in ids[1:3]:
            r = c.post(f"/api/measurements/{mid}/open", headers=JSON)
            assert r.status_code == 410 and "--history-max-gb" in r.json()["detail"]
            assert c.get(f"/api/measurements/{mid}").json()["distance_m"] > 0  # the numbers stay
        assert len(list((tmp_path / "h-frames").glob("*.frame"))) == 2
