"""Stereo footage from video files, through the same rectification and SGBM as a live pair.

Spec: ``video:PATH?layout=side-by-side|top-bottom&calib=FILE[&calib_units=mm&distortion=opencv|equidistant
&loop=0|1&realtime=0|1&scale=1&ndisp=..&block=..&mode=..]`` for one file holding both eyes (left half /
top half is the left camera), or ``video:LEFT,RIGHT?calib=FILE`` for one file per camera. ``calib`` takes
the project's JSON, OpenCV YAML/XML or a ROS camera_info pair (device/calibration/files.py).

Frames are decoded with OpenCV's FFmpeg backend and handed to :class:`device.sources.stereo_processing.StereoProcessor`.
What a file can do that a camera cannot, and how it is handled:

- **end of file** raises :class:`SourceEnded` (the live view keeps the last frame), or with ``loop=1``
  starts over with timestamps that keep increasing (one file duration per lap);
- **undecodable frames** (FFmpeg fails the read and goes on with the next frame) are skipped and counted
  per lap (``warnings``; the end's message names the count); so are frames the container lists but a
  truncated file lacks. A file of which no frame decodes ends at once, with ``loop=1`` too;
- **timestamps** are the container's presentation times (``CAP_PROP_POS_MSEC``; 0 on the first frame is
  a time, not "missing"); a file whose times do not increase falls back to ``index / fps``;
- ``realtime=1`` paces reads to those times (a video played at its speed); ``realtime=0`` (default)
  delivers frames as fast as they are processed;
- **odd sizes**: encoders with 4:2:0 chroma store even sizes only and drop the last row or column of an
  odd-sized frame (pixel (0, 0) stays put). When a decoded eye is one row/column short of the odd
  calibrated size, that row/column is repeated back so the calibration applies unchanged.

Codec: use a lossless one. FFV1 (``ffmpeg -i in -c:v ffv1 out.mkv``, or ``cv2.VideoWriter`` with
fourcc FFV1) decodes to the very pixels that were encoded, so disparity is identical to in-memory
images. Lossy codecs change pixel values enough to hurt SGBM: measured on the eight Middlebury scenes
(quarter size, one side-by-side frame written by OpenCV's writer at its default quality, share of
non-occluded pixels within 1 px of ground truth, 2026-12-01), FFV1 changes nothing, MJPG loses
0.11-0.26 and mp4v 0.15-0.36 (e.g. Motorcycle 0.916 -> 0.691 MJPG, 0.616 mp4v).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from measure import Frame, check_options, option

from device import configs
from device.base import SourceInfo, SourceSpec
from device.calibration.files import CalibrationRef
from device.errors import SourceEnded, SourceError, SourceNotFound
from device.sources.sgbm import SGBMConfig
from device.sources.stereo_processing import ProcessedPairSource

LAYOUTS = ("side-by-side", "top-bottom", "two-files")
MAX_UNLISTED_MISSES = 8  # failed reads in a row that end a file whose container lists no frame count
MAX_WARNINGS = 50
NEEDS_FILE = "a video: spec needs a file, e.g. video:pair.mkv?layout=side-by-side&calib=stereo.yaml"


@dataclass(frozen=True)
class VideoConfig:
    """Video file(s), how the eyes are laid out, calibration, playback and SGBM settings; spellings,
    bounds and help in each field's metadata (``device.configs`` parses specs, TOML and API bodies)."""

    paths: tuple[str, ...] = option(target=True, key="path", example=("pair.mkv",),
                                    help="one file holding both eyes, or LEFT,RIGHT: one file per eye")
    layout: str = option("", choices=LAYOUTS, default_text="side-by-side (two-files for two files)",
                         help="how one file holds the eyes: left | right halves, or left over right")
    calibration: CalibrationRef = option(factory=CalibrationRef, nested=True, help="the pair's calibration")
    loop: bool = option(False, help="start over at the end (timestamps keep increasing)")
    realtime: bool = option(False, help="pace reads to the file's timestamps (otherwise as fast as processed)")
    sgbm: SGBMConfig = option(factory=SGBMConfig, nested=True, help="SGBM settings")
    scale: float = option(1.0, min=0.1, max=1.0, help="rectification and SGBM on a pair downscaled by this")

    def __post_init__(self) -> None:
        if not self.paths:
            raise SourceError(NEEDS_FILE)
        if not self.layout:
            object.__setattr__(self, "layout", "two-files" if len(self.paths) == 2 else "side-by-side")
        check_options(self, SourceError, "video option ")
        if len(self.paths) == 2 and self.layout != "two-files":
            raise SourceError(f"two files are one per eye; drop layout={self.layout} (it is for one file holding both eyes)")
        want = 2 if self.layout == "two-files" else 1
        if len(self.paths) != want:
            raise SourceError(f"video layout {self.layout} needs {want} file(s), got {len(self.paths)}: "
                              f"{', '.join(self.paths)}")


def split_eyes(image: np.ndarray, layout: str) -> tuple[np.ndarray, np.ndarray]:
    """Left and right eye of a combined frame: left | right halves, or left over right."""
    if layout == "top-bottom":
        half = image.shape[0] // 2
        return image[:half], image[half:2 * half]
    half = image.shape[1] // 2
    return image[:, :half], image[:, half:2 * half]


def restore_odd_size(eye: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Repeat the last row/column that a 4:2:0 encoder dropped from an odd calibrated ``size`` (w, h).

    Only a shortfall of exactly one row (column) against an odd height (width) is restored; any other
    size is returned as it is, for the calibration's own size check to judge.
    """
    h, w = eye.shape[:2]
    pad_b = 1 if size[1] % 2 == 1 and h == size[1] - 1 else 0
    pad_r = 1 if size[0] % 2 == 1 and w == size[0] - 1 else 0
    if not (pad_b or pad_r):
        return eye
    return cv2.copyMakeBorder(eye, 0, pad_b, 0, pad_r, cv2.BORDER_REPLICATE)


class VideoGrabber:
    """(left, right, seconds) from one combined video or two per-eye videos (module docstring)."""

    def __init__(self, config: VideoConfig, calib_size: tuple[int, int] | None = None) -> None:
        self.config = config
        self.calib_size = calib_size
        self._caps: list[cv2.VideoCapture] = []
        self._index = 0
        self._lap_s = 0.0
        self._last_s = -np.inf
        self._fps = 30.0
        self._t0: tuple[float, float] | None = None  # (wall, video) times of the first delivered frame
        self._listed = 0  # frames the container says it holds (0: it does not say)
        self._lap_read = 0  # frames read (delivered or skipped) in the current lap
        self.skipped_in_lap = 0  # undecodable frames skipped in the current lap
        self.skipped_total = 0
        self.warnings: list[str] = []  # the newest skip messages, updated in place (a caller may hold it)
        self.position = -1  # the index in the file of the frame grab() returned last (-1: none yet)

    def open(self) -> None:
        self.close()
        for path in self.config.paths:
            if not Path(path).is_file():
                self.close()
                raise SourceNotFound(f"video file {path!r} does not exist; fix the path in the video: spec")
            cap = cv2.VideoCapture(path, cv2.CAP_FFMPEG)
            if not cap.isOpened():
                cap.release()
                self.close()
                raise SourceNotFound(f"cannot decode {path!r} as a video (OpenCV/FFmpeg); convert it, e.g. "
                                     "`ffmpeg -i IN -c:v ffv1 OUT.mkv`")
            self._caps.append(cap)
        fps = self._caps[0].get(cv2.CAP_PROP_FPS)
        self._fps = fps if np.isfinite(fps) and fps > 0 else 30.0
        counts = [cap.get(cv2.CAP_PROP_FRAME_COUNT) for cap in self._caps]
        self._listed = int(min(counts)) if all(np.isfinite(c) and c > 0 for c in counts) else 0
        self._index, self._lap_s, self._last_s, self._t0 = 0, 0.0, -np.inf, None
        self._lap_read, self.skipped_in_lap, self.skipped_total = 0, 0, 0
        self.warnings.clear()

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def frames(self) -> int:
        """Frames the container lists (0: it does not say)."""
        return self._listed

    def seek(self, i: int) -> None:
        """Make frame ``i`` of the file the next one ``grab`` returns (a replay bar's step back and scrub);
        exact for intra-only codecs such as FFV1. Raises IndexError outside the listed frames."""
        if not 0 <= i < max(self._listed, 1):
            raise IndexError(f"frame {i} is out of range: {' and '.join(self.config.paths)} lists {self._listed} frames")
        for cap in self._caps:
            cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        self._lap_read, self._t0 = i, None

    def _read_all(self) -> list[np.ndarray] | None:
        # Every capture reads, even after one failed: a failed read still moves past its frame, so the
        # eyes of two files stay in step.
        images = [cap.read() for cap in self._caps]
        return [img for _, img in images] if all(ok and img is not None for ok, img in images) else None

    def _next_images(self) -> list[np.ndarray] | None:
        """The next decodable frame of this lap, None at its end. FFmpeg fails one read for an undecodable
        frame and goes on with the next, so failed reads are retried: while the container lists more
        frames (at most ``MAX_UNLISTED_MISSES`` in a row when it lists none). Failed reads followed by a
        frame, or listed frames that never came (a truncated file), are counted as skipped."""
        misses = 0
        while True:
            images = self._read_all()
            if images is not None:
                self._skip(misses, "could not be decoded")
                self._lap_read += 1
                self.position = self._lap_read - 1
                return images
            misses += 1
            budget = self._listed - self._lap_read if self._listed else MAX_UNLISTED_MISSES
            if misses >= budget:
                if self._listed:
                    self._skip(max(budget, 0), "are listed by the container but could not be read (truncated or damaged)")
                return None

    def _skip(self, n: int, why: str) -> None:
        if n <= 0:
            return
        self._lap_read += n
        self.skipped_in_lap += n
        self.skipped_total += n
        names = " and ".join(self.config.paths)
        self.warnings.append(f"{names}: {n} frame(s) after frame {self._index} {why}; skipped")
        del self.warnings[:-MAX_WARNINGS]

    def _lap_note(self) -> str:
        return f" ({self.skipped_in_lap} undecodable frame(s) skipped)" if self.skipped_in_lap else ""

    def _rewind(self) -> None:
        for cap in self._caps:
            cap.set(cv2.CAP_PROP_POS_FRAMES, 0)

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
        if not self._caps:
            raise SourceError("the video grabber is not open")
        images = self._next_images()
        if images is None:
            names = " and ".join(self.config.paths)
            if self._index == 0:
                raise SourceEnded(f"no frame of {names} can be decoded{self._lap_note()}; convert it, e.g. "
                                  "`ffmpeg -i IN -c:v ffv1 OUT.mkv`")
            if not self.config.loop:
                raise SourceEnded(f"{names} ended after {self._index} frame(s){self._lap_note()}; add loop=1 to the "
                                  "video: spec to play it again")
            # Times keep increasing across laps: one frame period after the last frame.
            self._lap_s = self._last_s + 1.0 / self._fps
            self._rewind()
            self._lap_read, self.skipped_in_lap = 0, 0
            images = self._next_images()
            if images is None:
                raise SourceEnded(f"{self.config.paths[0]} cannot be rewound for loop=1; remux it "
                                  "(`ffmpeg -i IN -c copy OUT.mkv`)")
        stamp = self._timestamp()
        self._index += 1
        if self.config.realtime:
            self._pace(stamp)
        if self.config.layout == "two-files":
            left, right = images
            if left.shape != right.shape:
                raise SourceError(f"the two videos have different frame sizes {left.shape[1]}x{left.shape[0]} "
                                  f"and {right.shape[1]}x{right.shape[0]}; both eyes must use one size")
        else:
            left, right = split_eyes(images[0], self.config.layout)
        if self.calib_size is not None:
            left, right = restore_odd_size(left, self.calib_size), restore_odd_size(right, self.calib_size)
        return left, right, stamp

    def _timestamp(self) -> float:
        ms = self._caps[0].get(cv2.CAP_PROP_POS_MSEC)
        t = self._lap_s + ms / 1000.0 if np.isfinite(ms) and ms >= 0 else float("nan")
        if not (t > self._last_s):  # NaN or not increasing: the container has no usable times
            t = 0.0 if self._index == 0 else self._last_s + 1.0 / self._fps
        self._last_s = t
        return t

    def _pace(self, stamp: float) -> None:
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = (now, stamp)
            return
        wait = self._t0[0] + (stamp - self._t0[1]) - now
        if wait > 0:
            time.sleep(wait)

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []


class VideoSource(ProcessedPairSource):
    """Stereo video as a Source: :class:`VideoGrabber` + calibration + the live pair's StereoProcessor."""

    def __init__(self, config: VideoConfig) -> None:
        self.config = config
        self._grabber = VideoGrabber(config)
        self.warnings = self._grabber.warnings  # undecodable frames skipped (the service shows them)
        super().__init__(
            self._grabber, config.calibration, config.sgbm, config.scale,
            SourceInfo(kind="video", name=",".join(Path(p).name for p in config.paths),
                       extra={"layout": config.layout, "loop": config.loop, "realtime": config.realtime}),
            {"source": "video", "files": list(config.paths)},
        )

    def open(self) -> None:
        super().open()
        if self._processor is not None:
            w, h = self._processor.calibration.image_size
            self._grabber.calib_size = (int(w), int(h))
            self.info = SourceInfo(kind="video", name=self.info.name, width=w, height=h, fps=self._grabber.fps,
                                   state="playing", extra={**self.info.extra, "frames": self._grabber.frames})

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame, its index in the file in ``meta["frame_index"]`` (as a bag's frames carry theirs)."""
        frame = super().read(timeout_s)
        return dataclasses.replace(frame, meta={**frame.meta, "frame_index": self._grabber.position})

    def seek(self, i: int) -> None:
        """Make frame ``i`` of the file the next one ``read`` returns."""
        self._grabber.seek(i)


def config_from_spec(spec: SourceSpec) -> VideoConfig:
    """VideoConfig from a ``video:`` spec (module docstring)."""
    return configs.from_spec(VideoConfig, spec, SourceError(NEEDS_FILE))
