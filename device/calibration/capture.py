"""Live capture of calibration views: distinct ChArUco board views from a stereo grabber (cameras or a
video), kept when both cameras see enough corners and the board moved (a fraction of the image width)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from device.calibration.board import BoardDetector, BoardSpec
from device.calibration.solve import Progress
from device.errors import CalibrationError, SourceDisconnected


class PairGrabber(Protocol):
    """Where calibration views come from (same shape as ``stereo_pair.FrameGrabber``)."""

    def open(self) -> None: ...

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]: ...

    def close(self) -> None: ...


def capture_views(
    grabber: PairGrabber,
    board: BoardSpec,
    n_views: int,
    *,
    save_to: str | Path | None = None,
    progress: Progress | None = None,
    min_corners: int = 12,
    min_move: float = 0.02,
    max_seconds: float = 600.0,
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Collect ``n_views`` distinct board views from a stereo grabber (a camera pair or a video).

    A pair is kept when both cameras see at least ``min_corners`` common corners and the board
    moved by more than ``min_move`` x image width (mean corner shift) from every kept view, so that
    holding the board still does not fill the set with copies. ``grabber`` is any object with
    open/grab/close (``stereo_pair.V4L2Grabber``, ``video.VideoGrabber``, ``stereo_pair.ImagePairGrabber``);
    the caller builds it, so this package does not depend on the capture code (which depends on it).
    """
    say = progress or (lambda _msg: None)
    detector = BoardDetector(board)
    kept: list[tuple[str, np.ndarray, np.ndarray]] = []
    kept_corners: list[dict[int, np.ndarray]] = []
    out_dir = Path(save_to) if save_to else None
    if out_dir:
        (out_dir / "left").mkdir(parents=True, exist_ok=True)
        (out_dir / "right").mkdir(parents=True, exist_ok=True)
    grabber.open()
    deadline = time.monotonic() + max_seconds
    try:
        say(f"show the {board.squares_x}x{board.squares_y} ChArUco board to both cameras; "
            f"move it between views ({n_views} needed)")
        while len(kept) < n_views:
            if time.monotonic() > deadline:
                raise CalibrationError(f"only {len(kept)} of {n_views} views collected in {max_seconds:.0f} s; "
                                       "hold the whole board in view of both cameras, in good light")
            try:
                left, right, _ = grabber.grab(1.0)
            except SourceDisconnected:
                if len(kept) >= 6:
                    break  # a finite recording ran out; calibrate with what there is
                raise
            dl, dr = detector.detect(left), detector.detect(right)
            if dl is None or dr is None:
                continue
            common = np.intersect1d(dl.ids, dr.ids)
            if len(common) < min_corners:
                continue
            here = {int(i): c for i, c in zip(dl.ids, dl.corners)}
            width = left.shape[1]
            moved = True
            for prev in kept_corners:
                shared = [i for i in here if i in prev]
                if shared and np.mean([np.linalg.norm(here[i] - prev[i]) for i in shared]) < min_move * width:
                    moved = False
                    break
            if not moved:
                continue
            name = f"view{len(kept):03d}"
            kept.append((name, left.copy(), right.copy()))
            kept_corners.append(here)
            if out_dir:
                cv2.imwrite(str(out_dir / "left" / f"{name}.png"), left)
                cv2.imwrite(str(out_dir / "right" / f"{name}.png"), right)
            say(f"view {len(kept)}/{n_views}: {len(common)} corners")
    finally:
        grabber.close()
    return kept
