"""`video:` files with undecodable frames: FFmpeg fails the read of a damaged frame and goes on, so the frame
is skipped and counted per lap (not taken for the end of the file), a truncated file reports the listed
frames it lacks, the eyes of two files stay in step, and a file of which nothing decodes ends at once."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from device import SourceEnded
from device.sources.video import VideoConfig, VideoGrabber

W, H, N = 64, 48, 10


def write_mjpg(path: Path, n: int = N) -> Path:
    """Side-by-side frames whose grey level tells their number k (20 k)."""
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (W, H))
    assert writer.isOpened()
    for k in range(n):
        writer.write(np.full((H, W, 3), 20 * k, np.uint8))
    writer.release()
    return path


def garble(path: Path, frames) -> Path:
    """Overwrite the JPEG data of the given frames (keeping the container's chunk sizes) with noise."""
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i] == 0xFF and data[i + 1] == 0xD8]
    starts.append(len(data))
    rng = np.random.default_rng(0)
    for k in frames:
        a, b = starts[k], min(starts[k + 1] - 8, len(data))
        data[a:b] = rng.integers(0, 256, b - a, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    return path


def numbers(grabber: VideoGrabber, n: int) -> list[int]:
    out = []
    for _ in range(n):
        left, right, _ = grabber.grab()
        assert round(float(left.mean()) / 20) == round(float(right.mean()) / 20)
        out.append(round(float(left.mean()) / 20))
    return out


def grabber(*paths: Path, loop: bool = False) -> VideoGrabber:
    g = VideoGrabber(VideoConfig(paths=tuple(str(p) for p in paths), layout="two-files" if len(paths) == 2 else "side-by-side",
                                 loop=loop))
    g.open()
    return g


def test_an_undecodable_frame_is_skipped_not_taken_for_the_end(tmp_path: Path) -> None:
    g = grabber(garble(write_mjpg(tmp_path / "v.avi"), [4]))
    assert numbers(g, N - 1) == [0, 1, 2, 3, 5, 6, 7, 8, 9]
    with pytest.raises(SourceEnded, match=r"ended after 9 frame\(s\) \(1 undecodable frame\(s\) skipped\)"):
        g.grab()
    assert g.skipped_in_lap == 1 and len(g.warnings) == 1 and "after frame 4" in g.warnings[0]
    g.close()


def test_loop_counts_the_skips_per_lap(tmp_path: Path) -> None:
    g = grabber(garble(write_mjpg(tmp_path / "v.avi"), [0, 4]), loop=True)
    laps = 30
    stamps = []
    got = []
    for _ in range(8 * laps):
        left, _, t = g.grab()
        got.append(round(float(left.mean()) / 20))
        stamps.append(t)
    assert got == [1, 2, 3, 5, 6, 7, 8, 9] * laps
    assert g.skipped_in_lap == 2 and g.skipped_total == 2 * laps  # two per lap, never accumulating in a lap
    assert np.all(np.diff(stamps) > 0)
    g.close()


def test_a_truncated_file_reports_the_listed_frames_it_lacks(tmp_path: Path) -> None:
    path = write_mjpg(tmp_path / "v.avi")
    path.write_bytes(path.read_bytes()[: path.stat().st_size * 85 // 100])  # the index and the last frames lost
    g = grabber(path)
    listed = int(cv2.VideoCapture(str(path), cv2.CAP_FFMPEG).get(cv2.CAP_PROP_FRAME_COUNT))
    got = []
    with pytest.raises(SourceEnded, match="undecodable frame") as end:
        while True:
            got.append(numbers(g, 1)[0])
    assert got == list(range(len(got))) and 0 < len(got) < listed
    assert g.skipped_in_lap == listed - len(got), str(end.value)
    g.close()


def test_two_files_stay_in_step_past_a_damaged_frame(tmp_path: Path) -> None:
    left = garble(write_mjpg(tmp_path / "l.avi"), [3])
    right = write_mjpg(tmp_path / "r.avi")
    g = grabber(left, right)
    assert numbers(g, N - 1) == [0, 1, 2, 4, 5, 6, 7, 8, 9]  # numbers() checks both eyes show one frame
    g.close()


@pytest.mark.parametrize("loop", [False, True])
def test_a_file_with_no_decodable_frame_ends_at_once(tmp_path: Path, loop: bool) -> None:
    g = grabber(garble(write_mjpg(tmp_path / "v.avi"), range(N)), loop=loop)
    with pytest.raises(SourceEnded, match=r"no frame of .* can be decoded \(10 undecodable"):
        g.grab()
    g.close()
