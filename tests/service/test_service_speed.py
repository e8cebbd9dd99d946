"""What keeps the service fast under load: a slim paginated history list, JPEG for the live view,
thumbnails off the measuring path, frames presaved when frozen; and newer Measurement fields kept."""

from __future__ import annotations

import csv
import gc
import io
import os
import sys
import threading
import time

import cv2
import numpy as np
import pytest
from factories import wall_frame
from service_client import JSON, latest, make_client, measure


def test_history_list_is_slim_and_paginated(tmp_path):
    with make_client(tmp_path) as c:
        f = latest(c)
        c.post(f"/api/frames/{f['id']}/freeze", headers=JSON)
        ids = [measure(c, f["id"], (10, 10 + k), (300, 20 + k)).json()["id"] for k in range(7)]
        full = c.get(f"/api/measurements/{ids[0]}").json()
        assert len(full["samples_px"]) == full["n_samples"] > 100 and len(full["support"]) == full["n_samples"]
        page = c.get("/api/measurements", params={"limit": 3})
        items = page.json()
        assert [m["id"] for m in items] == ids[::-1][:3]
        assert all("samples_px" not in m and "support" not in m for m in items)
        slim = {k: v for k, v in full.items() if k not in ("samples_px", "support")}
        assert c.get("/api/measurements").json()[-1] == slim  # every other field, unchanged
        assert len(page.content) < 3 * 1200  # ~1 KB a record, not ~20 KB with the samples
        nxt = c.get("/api/measurements", params={"limit": 3, "before": items[-1]["id"]}).json()
        assert [m["id"] for m in nxt] == ids[::-1][3:6]
        last = c.get("/api/measurements", params={"limit": 3, "before": nxt[-1]["id"]}).json()
        assert [m["id"] for m in last] == ids[:1]


def test_the_collector_is_frozen_while_serving_once_per_process(tmp_path, monkeypatch):
    """The app freezes the collector's view while it serves and unfreezes it when it stops; an app
    started while the view is frozen already (another app serving, or the program that runs it: this
    suite's conftest after collection) leaves it as it is, so it pays no full pass and does not unfreeze
    the other's objects when it stops."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    full_passes: list[tuple] = []
    collect = gc.collect
    monkeypatch.setattr(gc, "collect", lambda *a: full_passes.append(a) or collect(*a))
    frozen_by_the_suite = gc.get_freeze_count() > 0
    gc.unfreeze()
    try:
        with make_client(tmp_path / "a") as first:
            latest(first)
            assert len(full_passes) == 1 and gc.get_freeze_count() > 0
            with make_client(tmp_path / "b") as second:
                latest(second)
            assert len(full_passes) == 1  # the second app paid no full pass ...
            assert gc.get_freeze_count() > 0  # ... and its end left the first's objects frozen
        assert gc.get_freeze_count() == 0
    finally:
        if frozen_by_the_suite:
            gc.freeze()


def _live_image_threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name.startswith("live-image")}


def test_live_view_jpeg_and_exact_png(tmp_path):
    before = _live_image_threads()  # another app's, alive in this process
    with make_client(tmp_path) as c:
        f = latest(c)
        c.post(f"/api/frames/{f['id']}/freeze", headers=JSON)
        want = wall_frame(c.get(f"/api/frames/{f['id']}").json()["meta"]["index"]).image
        jpg = c.get(f"/api/frames/{f['id']}/color.jpg")
        assert jpg.status_code == 200 and jpg.headers["content-type"] == "image/jpeg"
        img = cv2.imdecode(np.frombuffer(jpg.content, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == want.shape and np.abs(img.astype(int) - want).mean() < 3.0
        png = c.get(f"/api/frames/{f['id']}/color.png").content
        np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), want)
        live_images, ours = c.app.state.service.live_images, _live_image_threads() - before
        assert ours  # the JPEG was made on the app's own thread
    # the app's end stops its live-image thread: apps built one after another leave none behind
    with pytest.raises(RuntimeError, match="shutdown"):
        live_images.submit(int)
    assert not any(t.is_alive() for t in ours)


def test_thumbnail_is_drawn_on_request_not_when_measuring(tmp_path):
    with make_client(tmp_path) as c:
        f = latest(c)
        m = measure(c, f["id"], (10, 10), (300, 200), method="basic").json()
        store = c.app.state.store
        assert store.thumb(m["id"]) is None  # nothing drawn on the measuring path
        jpg = c.get(f"/api/measurements/{m['id']}/thumb.jpg")
        assert jpg.status_code == 200 and jpg.content[:3] == b"\xff\xd8\xff"
        thumb = cv2.imdecode(np.frombuffer(jpg.content, np.uint8), cv2.IMREAD_COLOR)
        assert thumb.shape == (180, 240, 3)
        # the segment is drawn where it was measured: (10,10)-(300,200) scaled by 240/320
        assert thumb[8, 8].tolist() != wall_frame(0).image[10, 10].tolist()
        assert store.thumb(m["id"]) == jpg.content  # kept
        png = c.get(f"/api/measurements/{m['id']}/thumb.png")
        assert png.content[:8] == b"\x89PNG\r\n\x1a\n"
    with make_client(tmp_path) as c:  # after a restart the frame is not in the ring: drawn from its saved file
        again = c.get(f"/api/measurements/{m['id']}/thumb.jpg")
        from_file = cv2.imdecode(np.frombuffer(again.content, np.uint8), cv2.IMREAD_COLOR)
        assert from_file.shape == thumb.shape
        assert np.abs(from_file.astype(int) - thumb).mean() < 2.0  # the same picture either way (0.8 on this frame)


def _freeze_and_wait_for_presave(c, tmp_path, fid: int):
    """Freeze frame ``fid``; returns its saved file once the background presave wrote it."""
    uid = c.post(f"/api/frames/{fid}/freeze", headers=JSON).json()["uid"]
    path = tmp_path / "h-frames" / f"{uid}.frame"
    deadline = time.monotonic() + 10
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert path.exists()
    return path


def test_frozen_frame_is_saved_before_the_measurement(tmp_path, monkeypatch):
    from history import frame_file

    with make_client(tmp_path) as c:
        f = latest(c)
        _freeze_and_wait_for_presave(c, tmp_path, f["id"])

        def no_writes(*_a, **_k):
            raise AssertionError("the measurement wrote the frame again")

        monkeypatch.setattr(frame_file, "write_durably", no_writes)
        r = measure(c, f["id"], (10, 10), (300, 200), method="basic")
        assert r.status_code == 200, r.text
        assert c.post(f"/api/measurements/{r.json()['id']}/open", headers=JSON).status_code == 200


def test_presaved_frame_never_measured_is_removed_at_restart(tmp_path):
    with make_client(tmp_path) as c:
        path = _freeze_and_wait_for_presave(c, tmp_path, latest(c)["id"])
    with make_client(tmp_path):
        assert not path.exists()


def test_newer_measurement_fields_are_stored_and_exported(tmp_path, monkeypatch):
    from measure import Measurement

    plain = Measurement.to_dict
    monkeypatch.setattr(
        Measurement, "to_dict", lambda self: {**plain(self), "quality": "good", "reasons": ["a", "b"], "interval_m": [1.0, 2.0]}
    )
    with make_client(tmp_path) as c:
        f = latest(c)
        m = measure(c, f["id"], (10, 10), (300, 200), method="basic").json()
        assert (m["quality"], m["reasons"], m["interval_m"]) == ("good", ["a", "b"], [1.0, 2.0])
        assert c.get("/api/measurements").json()[0]["quality"] == "good"
        rows = list(csv.DictReader(io.StringIO(c.get("/api/measurements.csv").text)))
        assert rows[0]["quality"] == "good" and rows[0]["reasons"] == "a; b"


@pytest.mark.parametrize("limit", [0, 10_001])
def test_list_limit_bounds(tmp_path, limit):
    with make_client(tmp_path) as c:
        assert c.get("/api/measurements", params={"limit": limit}).status_code == 422


def test_concurrent_measurements_share_one_commit(tmp_path):
    """Measurements that arrive while a commit (and its fsync) runs are committed together in the
    next one: 8 requests, 2 commits, each request answered with its own durable record."""
    import threading

    from history.store import Store

    store = Store(tmp_path / "h.db")
    frame = wall_frame(0)
    store.frames.save = lambda uid, f: 1000  # the frames are on disk already: only the rows commit
    commits: list[int] = []
    plain = store._commit

    def slow_first(batch):
        commits.append(len(batch))
        deadline = time.monotonic() + 10
        while len(commits) == 1 and len(store._pending) < 7 and time.monotonic() < deadline:
            time.sleep(0.005)  # the first commit's fsync lasts until the 7 others queued behind it
        plain(batch)

    store._commit = slow_first
    result = {"distance_m": 1.0, "method": "basic", "fit": "plane", "p1_m": [0, 0, 1], "p2_m": [1, 0, 1],
              "basic_distance_m": 1.0, "uncertainty_m": 0.01, "n_samples": 1, "n_valid": 1, "n_support": 1,
              "samples_px": [[0, 0]], "support": [True], "gap_detected": False, "warnings": [], "elapsed_ms": 1.0}  # fmt: skip
    records: dict[int, dict] = {}

    def add(k: int) -> None:
        records[k] = store.add(frame_id=k, frame_uid=f"u{k}", frame=frame, source="s", p1=(k, 0), p2=(k, 1), options={}, result=result)

    threads = [threading.Thread(target=add, args=(k,)) for k in range(8)]
    threads[0].start()
    while not commits:
        time.sleep(0.001)
    for t in threads[1:]:
        t.start()
    for t in threads:
        t.join(20)
    assert commits == [1, 7]
    assert sorted(records) == list(range(8)) and len({r["id"] for r in records.values()}) == 8
    store.close()
    reopened = Store(tmp_path / "h.db")  # what was answered is in the database
    for k, r in records.items():
        assert reopened.get(r["id"])["p1"] == [k, 0] and reopened.get(r["id"])["frame_id"] == k
    reopened.close()


def _result(n: int) -> dict:
    return {"distance_m": 1.0, "method": "basic", "fit": "plane", "p1_m": [0, 0, 1], "p2_m": [1, 0, 1],
            "basic_distance_m": 1.0, "uncertainty_m": 0.01, "n_samples": n, "n_valid": n, "n_support": n,
            "samples_px": [[k * 0.5, k * 0.25] for k in range(n)], "support": [True] * n, "gap_detected": False,
            "warnings": [], "elapsed_ms": 1.0}  # fmt: skip


def test_checkpoints_run_beside_the_commits(tmp_path, monkeypatch):
    """No measurement's commit copies the WAL into the database (SQLite's automatic checkpoint did,
    every ~1000 pages, ~140 measurements, for 50-350 ms); the checkpoint thread does, once the
    commits pause."""
    from history import checkpoint
    from history.store import Store

    monkeypatch.setattr(checkpoint, "QUIET_S", 3600.0)  # no checkpoint thread pass
    monkeypatch.setattr(checkpoint, "ROWS", 10**9)
    store = Store(tmp_path / "h.db")
    store.frames.save = lambda uid, f: 1000
    size0 = (tmp_path / "h.db").stat().st_size
    ids = [store.add(frame_id=k, frame_uid=f"u{k}", frame=wall_frame(0), source="s", p1=(k, 0), p2=(k, 1), options={},
                     result=_result(1280))["id"] for k in range(200)]  # fmt: skip
    assert (tmp_path / "h.db").stat().st_size == size0  # every page is still in the WAL
    assert store.get(ids[-1])["n_samples"] == 1280
    store.close()
    reopened = Store(tmp_path / "h.db")
    assert [reopened.get(i)["p1"] for i in ids] == [[k, 0] for k in range(200)]
    reopened.close()

    monkeypatch.setattr(checkpoint, "QUIET_S", 0.05)
    store = Store(tmp_path / "h2.db")
    store.frames.save = lambda uid, f: 1000
    for k in range(60):
        store.add(frame_id=k, frame_uid=f"u{k}", frame=wall_frame(0), source="s", p1=(k, 0), p2=(k, 1), options={}, result=_result(1280))
    deadline = time.monotonic() + 10
    while (tmp_path / "h2.db").stat().st_size < 512 * 1024 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert (tmp_path / "h2.db").stat().st_size >= 512 * 1024  # the checkpoint thread copied the rows
    store.close()


def test_capture_makes_the_live_jpeg_ahead_only_while_a_page_follows_every_frame():
    from device import SourceInfo
    from service.capture import Capture
    from service.frames import FrameRing
    from service.render import LIVE_JPEG, encode_jpeg

    ring = FrameRing(capacity=8)
    cap = Capture(lambda: None, ring, fps=10, backoff_initial_s=1, backoff_max_s=1)
    info = SourceInfo(kind="test", name="test")
    # what a long-poll woken by the push would find: the newest frame as it is when it becomes visible
    seen = []
    ring._wakers.add(lambda: seen.append(ring.latest().cached(LIVE_JPEG)))
    cap._deliver(wall_frame(0), info)  # nobody has looked yet
    assert ring.latest().cached(LIVE_JPEG) is None and seen == [None]
    ring.mark_viewed(ring.latest().id)  # a page shows frame 1 ...
    cap._deliver(wall_frame(1), info)  # ... so frame 2's JPEG is made before frame 2 can be seen
    entry = ring.latest()
    assert seen[-1] is not None and seen[-1] == entry.cached(LIVE_JPEG) == encode_jpeg(entry.frame.image)
    cap._deliver(wall_frame(2), info)  # the page did not ask for frame 2: nothing made ahead
    assert ring.latest().cached(LIVE_JPEG) is None and seen[-1] is None


def test_writes_in_one_turn_of_the_loop_reach_the_socket_as_one():
    import asyncio

    from service.connections import CoalescingTransport

    class Recorder:
        def __init__(self):
            self.writes, self.closed = [], False

        def write(self, data):
            self.writes.append(data)

        def is_closing(self):
            return self.closed

        def close(self):
            self.closed = True

        def get_write_buffer_size(self):
            return 0

    async def run():
        raw = Recorder()
        t = CoalescingTransport(raw)
        t.write(b"HTTP/1.1 200 OK\r\n\r\n")
        t.write(memoryview(b"body"))
        assert raw.writes == [] and t.get_write_buffer_size() == 23
        await asyncio.sleep(0)
        assert raw.writes == [b"HTTP/1.1 200 OK\r\n\r\nbody"]
        t.write(b"last")
        t.close()  # what is held goes out before the close
        assert raw.writes[-1] == b"last" and raw.closed
        await asyncio.sleep(0)
        assert len(raw.writes) == 2

    asyncio.run(run())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread niceness is Linux's")
def test_measurements_run_below_the_servers_other_threads():
    """The pool's threads run ``nice`` steps below the thread that made the pool, which keeps its own."""
    import asyncio
    import threading

    from service.workers import MeasurePool

    def own_nice() -> int:
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def niceness_in(pool: MeasurePool, calls: int) -> set[int]:
        async def run() -> list[int]:
            return list(await asyncio.gather(*(pool.run(own_nice) for _ in range(calls))))

        try:
            return set(asyncio.run(run()))
        finally:
            pool.close()

    server = own_nice()
    assert niceness_in(MeasurePool(workers=2, queue=2, nice=7), 4) == {min(server + 7, 19)}
    assert own_nice() == server
    assert niceness_in(MeasurePool(workers=1, queue=0, nice=0), 1) == {server}
