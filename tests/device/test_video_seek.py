"""A video file steps back and scrubs like a recording: ``VideoGrabber.seek(i)`` makes frame ``i`` the
next one, ``position`` is the index of the frame delivered, and the ``video:`` source carries it as
``meta["frame_index"]`` with the listed frame count in ``info.extra["frames"]``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from device.sources.video import VideoConfig, VideoGrabber

N = 6


def write_numbered(path: Path) -> Path:
    """Frame k of a side-by-side FFV1 file is grey level 20 * k in both eyes (lossless: exact levels)."""
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"FFV1"), 10.0, (64, 24))
    assert writer.isOpened()
    for k in range(N):
        writer.write(np.full((24, 64, 3), 20 * k, np.uint8))
    writer.release()
    return path


def level(grabber: VideoGrabber) -> int:
    left, right, _ = grabber.grab()
    assert int(left[0, 0, 0]) == int(right[0, 0, 0])
    return int(left[0, 0, 0]) // 20


def test_seek_delivers_that_frame_and_its_position(tmp_path: Path) -> None:
    g = VideoGrabber(VideoConfig(paths=(str(write_numbered(tmp_path / "n.mkv")),), layout="side-by-side"))
    g.open()
    try:
        assert g.frames == N
        assert [level(g) for _ in range(3)] == [0, 1, 2] and g.position == 2
        g.seek(4)  # scrub forward
        assert level(g) == 4 and g.position == 4
        g.seek(1)  # step back
        assert level(g) == 1 and g.position == 1
        assert level(g) == 2 and g.position == 2  # and on from there
        with pytest.raises(IndexError, match="lists 6 frames"):
            g.seek(N)
    finally:
        g.close()
