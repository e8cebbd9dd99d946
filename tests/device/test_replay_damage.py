"""`replay:` with damaged frames: skipped without recursion and counted per pass, the replay ends or loops as
asked, and a recording with no readable frame ends once instead of being reopened for ever."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from device import SourceEnded, open_source
from device.formats.recording import FRAMES, EndOfRecording, ReplaySource
from device.formats.recording.playback import NoReadableFrame
from factories import record


def with_missing_frames(path: Path, good: int, missing: int) -> Path:
    """A recording of ``good`` frames followed by ``missing`` index lines whose PNGs were never written."""
    record(path, good)
    index = path / FRAMES
    last = json.loads(index.read_text().splitlines()[-1])
    with index.open("a") as fh:
        for k in range(good, good + missing):
            line = dict(last, index=k, timestamp=last["timestamp"] + k,
                        files={kind: f"{kind}/{k:06d}.png" for kind in last["files"]})
            fh.write(json.dumps(line) + "\n")
    return path


def test_thousands_of_missing_frames_are_skipped_without_recursion(tmp_path: Path) -> None:
    """3000 unreadable frames after 2 good ones (the recursion limit is ~1000): loop=1 plays the two good
    frames pass after pass, counting 3000 skips per pass, never claiming that nothing can be read."""
    assert sys.getrecursionlimit() < 3000
    rec = with_missing_frames(tmp_path / "rec", 2, 3000)
    with open_source(f"replay:{rec}?loop=1") as src:
        got = [src.read().meta["k"] for _ in range(6)]
        assert got == [0, 1, 0, 1, 0, 1]
        assert src.playback.passes == 3 and src.playback.skipped_total == 2 * 3000  # 3000 per finished pass
        assert len(src.warnings) <= 50
    with open_source(f"replay:{rec}") as src:
        assert [src.read().meta["k"] for _ in range(2)] == [0, 1]
        with pytest.raises(EndOfRecording, match=r"3000 damaged frame\(s\) skipped in this pass: 2, 3, 4"):
            src.read()


def test_loop_with_one_corrupt_png_keeps_the_count_per_pass(tmp_path: Path) -> None:
    """One corrupt PNG among 6 frames, loop=1: 5 frames per pass for 40 passes, the skip count stays 1 per
    pass (it grew across passes until the replay claimed "no frame can be read")."""
    record(tmp_path / "rec", 6)
    (tmp_path / "rec" / "color" / "000003.png").write_bytes(b"not a png")
    with ReplaySource(tmp_path / "rec") as plain:
        assert [plain.read().meta["k"] for _ in range(5)] == [0, 1, 2, 4, 5]
        with pytest.raises(EndOfRecording, match=r"1 damaged frame\(s\) skipped in this pass: 3"):
            plain.read()
    with open_source(f"replay:{tmp_path / 'rec'}?loop=1") as src:
        got = [src.read().meta["k"] for _ in range(5 * 40)]
        assert got == [0, 1, 2, 4, 5] * 40
        assert list(src.playback.skipped) == [3] and src.playback.skipped_total == 40


@pytest.mark.parametrize("loop", [0, 1])
def test_a_recording_of_only_unreadable_frames_ends_once(tmp_path: Path, loop: int) -> None:
    record(tmp_path / "rec", 4)
    for png in (tmp_path / "rec" / "disparity").glob("*.png"):
        png.write_bytes(png.read_bytes()[:100])
    with open_source(f"replay:{tmp_path / 'rec'}?loop={loop}") as src:
        with pytest.raises(NoReadableFrame, match="no frame of the replay .* can be read") as err:
            src.read()
        assert isinstance(err.value, SourceEnded)  # a live view ends here: reopening would fail the same way
        assert src.playback.skipped_total == 4


def test_start_and_seek_skip_damaged_frames_too(tmp_path: Path) -> None:
    record(tmp_path / "rec", 5)
    (tmp_path / "rec" / "color" / "000004.png").unlink()
    with open_source(f"replay:{tmp_path / 'rec'}?start=3&loop=1") as src:
        assert [src.read().meta["k"] for _ in range(3)] == [3, 0, 1]  # 4 is skipped, the loop starts again at 0
        src.seek(4)
        assert src.read().meta["k"] == 0
        with pytest.raises(IndexError, match="out of range"):
            src.seek(5)
