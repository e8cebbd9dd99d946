"""`bag:` with damaged messages: the frame is skipped and counted per pass, the bag ends or loops as asked,
a bag with no readable frame ends once (the service does not reopen it), and the service plays on."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from bag_writers import PERIOD, T0, write_timed_bag
from device import SourceEnded, open_source
from device.formats.recording import EndOfRecording
from device.formats.recording.playback import NoReadableFrame
from device.sources.bag import BagError, BagReader

N = 6


def numbers(src, n: int) -> list[int]:
    """The numbers (pixel values) of the next ``n`` frames."""
    return [int(src.read().image[0, 0, 0]) for _ in range(n)]


@pytest.mark.parametrize("damage", ["cut", "short"])
@pytest.mark.parametrize("kind", ["ros1", "mcap", "sqlite3"])
def test_damaged_depth_message_is_skipped_and_the_bag_ends(tmp_path: Path, kind: str, damage: str) -> None:
    bag = write_timed_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, T0 + PERIOD * np.arange(N),
                          **{damage: (2,)})
    with BagReader(bag) as br:
        with pytest.raises(BagError, match="damaged|cannot be decoded"):
            br.frame(2)  # random access says what is wrong
    with open_source(f"bag:{bag}") as src:
        assert numbers(src, N - 1) == [0, 1, 3, 4, 5]
        with pytest.raises(EndOfRecording, match=r"1 damaged frame\(s\) skipped in this pass: 2") as end:
            src.read()
        assert not isinstance(end.value, NoReadableFrame)
        assert list(src.playback.skipped) == [2] and src.playback.skipped_total == 1
        assert len(src.warnings) == 1 and "frame 2 skipped" in src.warnings[0]


def test_loop_counts_skips_per_pass_and_never_claims_nothing_readable(tmp_path: Path) -> None:
    bag = write_timed_bag(tmp_path / "b", "mcap", T0 + PERIOD * np.arange(N), cut=(2,))
    with open_source(f"bag:{bag}?loop=1&start=4") as src:
        got = numbers(src, 2 + 5 * 20)  # frames 4, 5, then twenty passes of the five good ones
        assert got == [4, 5] + [0, 1, 3, 4, 5] * 20
        assert src.playback.passes == 21 and list(src.playback.skipped) == [2]  # one skip in this pass
        assert src.playback.skipped_total == 20  # one per pass, never more
        assert len(src.warnings) <= 50


@pytest.mark.parametrize("loop", [0, 1])
def test_a_bag_of_only_damaged_frames_ends_once(tmp_path: Path, loop: int) -> None:
    """Every frame damaged: one read tries each once and ends with NoReadableFrame (a SourceEnded, so a
    live view does not reopen it), with loop=1 too (no endless loop, no recursion)."""
    bag = write_timed_bag(tmp_path / "b", "mcap", T0 + PERIOD * np.arange(N), cut=range(N))
    with open_source(f"bag:{bag}?loop={loop}") as src:
        with pytest.raises(NoReadableFrame, match="no frame of the bag .* can be read") as err:
            src.read()
        assert isinstance(err.value, SourceEnded)
        assert src.playback.skipped_total == N


def test_service_plays_past_a_damaged_frame_and_ends(tmp_path: Path) -> None:
    """The case that reconnected 41 times in 40 s: the service delivers the five good frames once, ends,
    and never reopens the bag."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    bag = write_timed_bag(tmp_path / "b", "mcap", T0 + PERIOD * np.arange(N), cut=(2,))
    app = create_app(f"bag:{bag}", db_path=tmp_path / "h.db", capture_fps=200.0, reconnect_initial_s=0.02)
    with TestClient(app, base_url="http://127.0.0.1") as c:
        deadline = time.monotonic() + 20
        while c.get("/api/source").json()["state"] != "ended" and time.monotonic() < deadline:
            time.sleep(0.02)
        s = c.get("/api/source").json()
    assert s["state"] == "ended", s
    assert "1 damaged frame(s) skipped in this pass: 2" in s["message"], s
    assert s["retries"] == 0 and s["frames"] == N - 1, s
    assert any("frame 2 skipped" in w for w in s["warnings"]), s
