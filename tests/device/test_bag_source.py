"""The `bag:` source: random access, start, loop, realtime playback on a fake clock (device/pacing.py's
Pacer, no wall-clock time), the measure command and the service on a bag."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from bag_writers import N_FRAMES, PERIOD, T0, Capture, make_capture, write_ros_bag, write_timed_bag, write_viewer_bag
from device import SourceError, SourceTimeout, open_source
from factories import FakeClock


@pytest.fixture(scope="module")
def capture() -> Capture:
    return make_capture()


def test_random_access_and_start(capture, tmp_path: Path) -> None:
    bag = write_ros_bag(tmp_path / "rs", capture, "mcap", "realsense-ros")
    with open_source(f"bag:{bag}?start=2") as src:
        assert len(src) == N_FRAMES and src.read().meta["frame_index"] == 2
        f1 = src.frame(1)
        assert np.array_equal(f1.image, capture.frames[1].image)
        src.seek(0)
        assert src.read().meta["frame_index"] == 0
    with open_source(f"bag:{bag}?loop=1") as src:
        assert [src.read().meta["frame_index"] for _ in range(N_FRAMES + 1)] == [0, 1, 2, 0]


@pytest.mark.parametrize("options", ["", "?realtime=1"])
def test_measure_command_on_a_bag(capture, tmp_path: Path, clock: FakeClock, options: str) -> None:
    """`measure --frame 2` reads frame 2 directly: realtime=1 makes it wait for no frame before it."""
    from typer.testing import CliRunner

    from cli.main import app

    bag = write_ros_bag(tmp_path / "rs", capture, "mcap", "realsense-ros")
    truth = capture.frames[2].meta["truth"]
    p1, p2 = (f"{x:g},{y:g}" for x, y in (truth.p1_px, truth.p2_px))
    res = CliRunner().invoke(app, ["measure", f"bag:{bag}{options}", "--p1", p1, "--p2", p2, "--frame", "2", "--json"])
    assert res.exit_code == 0, res.output
    assert abs(json.loads(res.output)["distance_m"] - truth.length_m) < 0.02
    assert clock.sleeps == []  # reading frames 0-2 in turn would have slept 2 x 33 ms


# ---------------------------------------------------------------------------------------------
# realtime playback: device/pacing.py's Pacer on a fake clock (no wall-clock time)

MS = 1_000_000
PACED_MS = (0, 125, 250, 750, 875)  # 125 ms apart with one 500 ms gap (binary fractions: exact due times)


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    import device.pacing as pacing

    fake = FakeClock()
    monkeypatch.setattr(pacing, "time", fake)
    return fake


def play(src, clock: FakeClock, n: int, timeout_s: float = 1.0) -> list[tuple[int, float]]:
    """Read ``n`` frames: each one's number (its pixel value) and when it came (s after the first read)."""
    t0, out = clock.now, []
    for _ in range(n):
        f = src.read(timeout_s)
        out.append((int(f.image[0, 0, 0]), clock.now - t0))
    return out


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_realtime_paces_on_record_times(clock: FakeClock, tmp_path: Path, kind: str) -> None:
    """realtime=1 waits out each gap between the frames' record times, the 500 ms one too; the header
    stamps (here 1/30 s apart) are what the frames carry, not what sets the pace."""
    stamps = [T0 + k * PERIOD for k in range(5)]
    bag = write_timed_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, [T0 + t * MS for t in PACED_MS], stamps)
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert [src.frame(k).timestamp for k in range(5)] == [t / 1e9 for t in stamps]
        assert clock.sleeps == []  # frame(k) waits for nothing
        assert play(src, clock, 5) == [(0, 0.0), (1, 0.125), (2, 0.25), (3, 0.75), (4, 0.875)]
    assert clock.sleeps == [0.125, 0.125, 0.5, 0.125]


def test_realtime_speed_start_loop_and_off(clock: FakeClock, tmp_path: Path) -> None:
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1&speed=2") as src:
        assert play(src, clock, 5) == [(0, 0.0), (1, 0.0625), (2, 0.125), (3, 0.375), (4, 0.4375)]
    # start=3: frame 3 is due at once; at the end the loop starts again with frame 0 due at once
    with open_source(f"bag:{bag}?realtime=1&loop=1&start=3") as src:
        assert play(src, clock, 6) == [(3, 0.0), (4, 0.125), (0, 0.125), (1, 0.25), (2, 0.375), (3, 0.875)]
    clock.sleeps.clear()
    with open_source(f"bag:{bag}?loop=1") as src:
        assert play(src, clock, 7) == [(k % 5, 0.0) for k in range(7)]
    assert clock.sleeps == []
    with pytest.raises(SourceError, match="speed=0.0 must be a positive number"):
        open_source(f"bag:{bag}?realtime=1&speed=0")


def test_realtime_gap_past_the_timeout_times_out_then_plays_on(clock: FakeClock, tmp_path: Path) -> None:
    """A frame due after the read's timeout raises SourceTimeout after that timeout, as a live camera
    with no frame would, and is the next frame read: no frame skipped, the pace kept."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 3) == [(0, 0.0), (1, 0.125), (2, 0.25)]
        with pytest.raises(SourceTimeout, match="due in 0.50 s, after the 0.25 s timeout"):
            src.read(timeout_s=0.25)
        assert play(src, clock, 2) == [(3, 0.25), (4, 0.375)]
    assert clock.sleeps == [0.125, 0.125, 0.25, 0.25, 0.125]


def test_realtime_seek_and_slow_reader(clock: FakeClock, tmp_path: Path) -> None:
    """seek(k) makes frame k due at once; a reader slower than the bag gets the frames already due without
    a wait, and the pace holds to the record times (frame k at PACED_MS[k] after the start), not drifting."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 1) == [(0, 0.0)]
        src.seek(3)
        assert play(src, clock, 2) == [(3, 0.0), (4, 0.125)]
        src.seek(0)
        t0 = clock.now
        src.read()
        clock.now += 0.375  # processing frame 0 took 0.375 s: frames 1 and 2 are late, frame 3 is due at 0.75
        assert play(src, clock, 3) == [(1, 0.0), (2, 0.0), (3, 0.375)]
        assert clock.now - t0 == 0.75


def test_realtime_unpaired_colour_message_keeps_its_neighbours_times(clock: FakeClock, tmp_path: Path) -> None:
    """Colour message 2 has no depth, so it is no frame: frame 2 is message 3, due at message 3's time."""
    bag = write_timed_bag(tmp_path / "b", "mcap", [T0 + t * MS for t in PACED_MS], no_depth=(2,))
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert len(src) == 4
        assert play(src, clock, 4) == [(0, 0.0), (1, 0.125), (3, 0.75), (4, 0.875)]


@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_realtime_record_times_out_of_order_or_repeated(clock: FakeClock, tmp_path: Path, kind: str) -> None:
    """Messages written out of record-time order play in record-time order; two frames with one record time
    come together; header stamps going backwards change nothing. No wait is negative (FakeClock refuses
    one, as time.sleep does) and none is added."""
    rec_ms = (0, 125, 500, 250, 250, 625)  # message 2 recorded after 3 and 4 but written before them
    stamp_ms = (0, 100, 50, 300, 300, 10)  # stamps going back twice
    bag = write_timed_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind,
                          [T0 + t * MS for t in rec_ms], [T0 + t * MS for t in stamp_ms])
    with open_source(f"bag:{bag}?realtime=1") as src:
        assert play(src, clock, 6) == [(0, 0.0), (1, 0.125), (3, 0.25), (4, 0.25), (2, 0.5), (5, 0.625)]
    assert clock.sleeps == [0.125, 0.125, 0.25, 0.125]


def test_service_serves_a_bag(capture, tmp_path: Path) -> None:
    """`depthruler serve --source bag:...`: the frames stream, the bag ends like a replay, and a click measures."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    bag = write_viewer_bag(tmp_path / "viewer.bag", capture)
    with TestClient(create_app(f"bag:{bag}", db_path=tmp_path / "h.db", capture_fps=200.0, reconnect_initial_s=0.02), base_url="http://127.0.0.1") as c:
        deadline = time.monotonic() + 20
        while c.get("/api/source").json()["state"] != "ended" and time.monotonic() < deadline:
            time.sleep(0.02)
        s = c.get("/api/source").json()
        assert s["state"] == "ended" and s["frames"] == N_FRAMES, s
        f = c.get("/api/frames/latest", params={"after": 0, "wait": 5}).json()
        truth = capture.frames[-1].meta["truth"]
        r = c.post("/api/measure", json={"frame_id": f["id"], "p1": list(truth.p1_px), "p2": list(truth.p2_px), "options": {}})
        assert r.status_code == 200, r.text
        assert abs(r.json()["distance_m"] - truth.length_m) < 0.02
