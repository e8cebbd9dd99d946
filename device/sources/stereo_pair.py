"""A V4L2 stereo pair (one side-by-side UVC camera or two nodes) with OpenCV SGBM, as Frames: capture.

Capture and processing are separate so tests drive the real processing with recorded or rendered pairs:
:class:`V4L2Grabber` grabs (left, right, timestamp in s) from cameras (any ``cv2.VideoCapture``-like
object can be injected), :class:`ImagePairGrabber` from memory; ``device.sources.stereo_processing``
rectifies them and runs SGBM, registered to the *rectified left* colour image.

Spec: ``v4l2:/dev/video0?layout=side-by-side&calib=FILE[&calib_units=mm&distortion=opencv|equidistant
&size=1280x480&fps=30&fourcc=MJPG&mode=sgbm_3way&ndisp=64&block=5&wls=0&lr_confidence=1&fill_left_band=1
&scale=1]`` or ``v4l2:/dev/video0,/dev/video2?calib=...`` (size is per node: both halves together for a
side-by-side camera). ``calib`` is the project's JSON, an OpenCV YAML/XML or a ROS ``left.yaml,right.yaml``.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from measure import check_options, option

from device import configs
from device.base import SourceInfo, SourceSpec
from device.calibration.files import CalibrationRef
from device.calibration.stereo import StereoCalibration
from device.errors import SourceDisconnected, SourceEnded, SourceError, SourceNotFound, SourceTimeout
from device.sources.sgbm import SGBMConfig
from device.sources.stereo_processing import FrameGrabber, ProcessedPairSource

log = logging.getLogger(__name__)
LAYOUTS = ("side-by-side", "two-nodes")
NO_CAMERA_HINT = (
    "plug in the stereo camera and check `depthruler devices` (or `v4l2-ctl --list-devices`); "
    "in a container pass --device /dev/videoN; or use the simulator: `depthruler serve --source sim`"
)


@dataclass(frozen=True)
class StereoPairConfig:
    """Capture settings (per V4L2 node), calibration file and SGBM settings of a stereo pair.

    Defaults give 640x480 per eye with SGBM_3WAY, no WLS, no right matcher: the configuration
    that keeps live view at >= 10 fps on a 2-core machine (bench/RESULTS.md "## SGBM"; 1280x720
    eyes run at about half that). ``scale`` < 1 runs rectification and SGBM on a downscaled pair
    (faster live view; the intrinsics are scaled with it). ``max_skew_s`` bounds the timestamp gap
    of a two-node pair (default: half a frame period).
    """

    devices: tuple[str, ...] = option(("/dev/video0",), target=True, key="device", example=("/dev/video2",),
                                      help="the V4L2 node of a side-by-side camera, or LEFT,RIGHT: one node per eye")
    layout: str = option("", choices=LAYOUTS, default_text="side-by-side (two-nodes for two devices)",
                         help="one camera giving both eyes side by side, or one node per eye")
    fourcc: str = option("MJPG", case="upper", example="YUYV", help="the pixel format asked of the driver (four characters)")
    width: int | None = option(None, joined=("size", 0), min=16, unit="px", example=640,
                               default_text="1280x480 side-by-side, 640x480 per node", help="capture width per node")
    height: int | None = option(None, joined=("size", 1), min=16, unit="px", example=360, help="capture height per node")
    fps: float = option(30.0, min=0.0, max=240.0, min_open=True, unit="frames/s", help="capture frame rate asked of the driver")
    calibration: CalibrationRef = option(factory=CalibrationRef, nested=True, help="the pair's calibration")
    sgbm: SGBMConfig = option(factory=SGBMConfig, nested=True, help="SGBM settings")
    scale: float = option(1.0, min=0.1, max=1.0, help="rectification and SGBM on a pair downscaled by this")
    max_skew_s: float | None = option(None, min=0.0, min_open=True, unit="s", default_text="half a frame period",
                                      help="largest timestamp gap of a two-node pair")

    def __post_init__(self) -> None:
        if not self.layout:
            object.__setattr__(self, "layout", "two-nodes" if len(self.devices) == 2 else "side-by-side")
        if self.width is None or self.height is None:
            w, h = (1280, 480) if self.layout == "side-by-side" else (640, 480)
            object.__setattr__(self, "width", self.width or w)
            object.__setattr__(self, "height", self.height or h)
        check_options(self, SourceError, "v4l2 option ")
        want = 1 if self.layout == "side-by-side" else 2
        if len(self.devices) != want:
            raise SourceError(
                f"layout {self.layout} needs {want} device node(s), got {len(self.devices)}: {', '.join(self.devices)}"
            )
        if len(self.fourcc) != 4:
            raise SourceError(f"v4l2 option fourcc={self.fourcc!r} must have four characters, e.g. MJPG or YUYV")
        if self.layout == "side-by-side" and self.width % 2:  # type: ignore[operator]
            raise SourceError(f"v4l2 option size={self.width}x{self.height}: side-by-side needs an even width")

    @property
    def eye_size(self) -> tuple[int, int]:
        """Size of one camera's image as captured."""
        w, h = int(self.width or 0), int(self.height or 0)
        return (w // 2, h) if self.layout == "side-by-side" else (w, h)


def open_v4l2(device: str) -> Capture:
    """The real capture: ``cv2.VideoCapture(device, CAP_V4L2)``."""
    import cv2

    return cv2.VideoCapture(device, cv2.CAP_V4L2)


class Capture(Protocol):
    """The part of ``cv2.VideoCapture`` the grabber uses (tests inject a fake with the same methods)."""

    def isOpened(self) -> bool: ...

    def set(self, prop: int, value: float) -> bool: ...

    def get(self, prop: int) -> float: ...

    def grab(self) -> bool: ...

    def retrieve(self) -> tuple[bool, np.ndarray | None]: ...

    def release(self) -> None: ...


def fourcc_text(code: float) -> str:
    """The four characters of an OpenCV FOURCC property value ("" when the backend reports none)."""
    n = int(code)
    text = "".join(chr((n >> (8 * i)) & 0xFF) for i in range(4))
    return text if n > 0 and text.isprintable() else ""


def node_access_problem(device: str) -> str:
    """Why a V4L2 node cannot be opened, from the OS: "" (no problem seen), or a message for
    permission denied / busy. Permission is not "busy": it is fixed by a group, not by closing a program."""
    import errno

    try:
        fd = os.open(device, os.O_RDWR | os.O_NONBLOCK)
    except PermissionError:
        return (f"permission denied on {device}: add your user to the 'video' group "
                "(`sudo usermod -aG video $USER`, then log out and in) or run with access to the device")
    except OSError as exc:
        if exc.errno == errno.EBUSY:
            return f"{device} is busy: another program is capturing from it; close it and retry"
        return f"{device} cannot be opened ({exc.strerror})"
    os.close(fd)
    return ""


class V4L2Grabber:
    """Pairs from V4L2 through ``cv2.VideoCapture(..., CAP_V4L2)``: a side-by-side node or two nodes.

    Every capture call runs on one capture thread and the caller waits at most ``timeout_s``:
    OpenCV's V4L2 backend ignores ``CAP_PROP_READ_TIMEOUT_MSEC`` and blocks ~10 s on a stalled
    camera. A wait that ends without a frame is :class:`SourceTimeout` while the node still exists
    (the call stays pending and the next ``grab`` waits for it instead of queueing another), and
    :class:`SourceDisconnected` when the node is gone or the driver reports a failed grab.
    Two nodes are ``grab()``-bed back to back and ``retrieve()``-d (decoded) afterwards, which keeps
    the two exposures closer than two ``read()``s. After ``open`` the format and rate the driver
    really gave are read back; a fallback (MJPG -> YUYV, a lower fps) is logged and listed in
    ``warnings``.
    """

    def __init__(self, config: StereoPairConfig, read_timeout_ms: int = 2000,
                 capture_factory: Callable[[str], Capture] = open_v4l2) -> None:
        self.config = config
        self.read_timeout_ms = read_timeout_ms
        self._factory = capture_factory
        self._caps: list[Capture] = []
        self._worker: ThreadPoolExecutor | None = None
        self._pending: Future | None = None
        self.warnings: list[str] = []
        self.actual_fps = config.fps
        self.actual_fourcc = config.fourcc

    def open(self) -> None:
        import cv2

        cfg = self.config
        self.warnings = []
        for dev in cfg.devices:
            if dev.startswith("/") and not Path(dev).exists():
                self.close()
                raise SourceNotFound(f"no V4L2 device {dev}; {NO_CAMERA_HINT}")
            cap = self._factory(dev)
            if not cap.isOpened():
                cap.release()
                self.close()
                problem = node_access_problem(dev) if dev.startswith("/") else ""
                raise SourceNotFound(
                    f"cannot open {dev} as a V4L2 camera: {problem}" if problem else
                    f"cannot open {dev} as a V4L2 camera (a metadata node? UVC cameras expose two nodes and only "
                    f"one captures: see `depthruler devices`); {NO_CAMERA_HINT}"
                )
            self._caps.append(cap)
            # Order matters: many UVC drivers accept a size only after the MJPG format is chosen and
            # silently fall back to 640x480 otherwise, so read everything back.
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*cfg.fourcc))
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, cfg.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, cfg.height)
            cap.set(cv2.CAP_PROP_FPS, cfg.fps)
            cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
            got = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            if got != (cfg.width, cfg.height):
                self.close()
                raise SourceError(
                    f"{dev} delivers {got[0]}x{got[1]} although {cfg.width}x{cfg.height} {cfg.fourcc} was asked; "
                    "set size= to a mode the camera lists (`v4l2-ctl -d DEV --list-formats-ext`)"
                )
            fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
            fps = float(cap.get(cv2.CAP_PROP_FPS))
            if fourcc and fourcc != cfg.fourcc:
                self.warnings.append(f"{dev} delivers {fourcc} although {cfg.fourcc} was asked (the driver fell back; "
                                     "uncompressed formats need far more USB bandwidth: expect a lower rate)")
                self.actual_fourcc = fourcc
            if fps > 0 and fps < 0.95 * cfg.fps:
                self.warnings.append(f"{dev} runs at {fps:g} fps although {cfg.fps:g} was asked (the mode does not "
                                     "support it at this size/format; check `v4l2-ctl -d DEV --list-formats-ext`)")
                self.actual_fps = min(self.actual_fps, fps)
        for w in self.warnings:
            log.warning(w)
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="v4l2-capture")

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
        if not self._caps or self._worker is None:
            raise SourceError("the V4L2 grabber is not open")
        future = self._pending or self._worker.submit(self._capture, timeout_s)
        self._pending = None
        try:
            left, right, stamp = future.result(timeout=timeout_s)
        except FutureTimeout:
            self._pending = future  # still blocked in the driver: wait for this call next time
            gone = [d for d in self.config.devices if d.startswith("/") and not Path(d).exists()]
            if gone:
                raise SourceDisconnected(f"{', '.join(gone)} disappeared (unplugged?); check the cable and reopen "
                                         "the source") from None
            raise SourceTimeout(f"no frame from {', '.join(self.config.devices)} within {timeout_s:.1f} s; the camera "
                                "is connected but stalled (USB bandwidth? another program?)") from None
        return left, right, stamp

    def _capture(self, timeout_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Runs on the capture thread: grab every node, pair by time, then retrieve (decode)."""
        stamps = [self._grab(i) for i in range(len(self._caps))]
        if len(self._caps) == 2:
            # Two free-running cameras: grab the one that lags until the timestamps agree within the
            # skew bound (half a frame period by default); only then decode.
            skew = self.config.max_skew_s if self.config.max_skew_s is not None else 0.5 / self.config.fps
            # Give up a little before the caller's wait ends, so the caller hears why (drift, not a stall).
            deadline = time.monotonic() + 0.8 * timeout_s
            while abs(stamps[0] - stamps[1]) > skew:
                if time.monotonic() > deadline:
                    raise SourceTimeout(
                        f"no left/right frames within {skew * 1000:.0f} ms of each other for {timeout_s:.1f} s "
                        f"(last gap {abs(stamps[0] - stamps[1]) * 1000:.0f} ms); use one fps for both cameras or "
                        "raise max_skew_s"
                    )
                lag = 0 if stamps[0] < stamps[1] else 1
                stamps[lag] = self._grab(lag)
        images = [self._retrieve(i) for i in range(len(self._caps))]
        if len(images) == 1:
            half = images[0].shape[1] // 2
            return images[0][:, :half], images[0][:, half:2 * half], stamps[0]
        return images[0], images[1], (stamps[0] + stamps[1]) / 2.0

    def _grab(self, i: int) -> float:
        import cv2

        cap = self._caps[i]
        if not cap.grab():
            raise SourceDisconnected(
                f"{self.config.devices[i]} stopped delivering frames (unplugged?); check the cable and reopen the source"
            )
        # OpenCV's V4L2 backend reports the buffer time (CLOCK_MONOTONIC, ms); 0 when the driver gives none.
        ms = cap.get(cv2.CAP_PROP_POS_MSEC)
        return ms / 1000.0 if ms > 0 else time.monotonic()

    def _retrieve(self, i: int) -> np.ndarray:
        ok, img = self._caps[i].retrieve()
        if not ok or img is None:
            raise SourceDisconnected(f"{self.config.devices[i]} delivered a frame that cannot be decoded; "
                                     "check the cable (a corrupt MJPG stream) and reopen the source")
        return img

    def close(self) -> None:
        worker, caps = self._worker, self._caps
        self._worker, self._pending, self._caps = None, None, []
        if worker is None:
            _release(caps)
            return
        # Released on the capture thread, after any call still blocked in the driver (OpenCV gives up
        # after ~10 s): releasing a capture under a running grab() is a use-after-free. No waiting here.
        worker.submit(_release, caps)
        worker.shutdown(wait=False)


def _release(caps: list[Capture]) -> None:
    for cap in caps:
        cap.release()


class ImagePairGrabber:
    """Pairs from memory (recorded or rendered), through the same interface as the cameras.

    Each ``grab`` returns the next pair; after the last one it raises :class:`SourceEnded`
    (end of data) unless ``loop``. Timestamps are ``index / fps``.
    """

    def __init__(self, pairs: Sequence[tuple[np.ndarray, np.ndarray]], *, loop: bool = False, fps: float = 10.0):
        if not pairs:
            raise SourceError("ImagePairGrabber needs at least one (left, right) pair")
        self.pairs = list(pairs)
        self.loop = loop
        self.fps = fps
        self._i = 0

    def open(self) -> None:
        self._i = 0

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
        if self._i >= len(self.pairs):
            if not self.loop:
                raise SourceEnded(f"all {len(self.pairs)} image pairs were read; reopen to start again")
            self._i = 0
        left, right = self.pairs[self._i % len(self.pairs)]
        stamp = self._i / self.fps
        self._i += 1
        return left, right, stamp

    def close(self) -> None:
        pass


class StereoPairSource(ProcessedPairSource):
    """A live stereo pair as a Source: V4L2 grabber (unless another is given) + calibration + SGBM."""

    def __init__(
        self,
        config: StereoPairConfig = StereoPairConfig(),
        *,
        grabber: FrameGrabber | None = None,
        calibration: StereoCalibration | None = None,
    ) -> None:
        self.config = config
        w, h = config.eye_size
        super().__init__(
            grabber if grabber is not None else V4L2Grabber(config),
            calibration if calibration is not None else config.calibration,
            config.sgbm,
            config.scale,
            SourceInfo(kind="v4l2", name=",".join(config.devices), width=w, height=h, fps=config.fps,
                       extra={"layout": config.layout}),
            {"source": "v4l2", "devices": list(config.devices)},
        )

    def open(self) -> None:
        super().open()
        grabber = self.grabber
        if isinstance(grabber, V4L2Grabber):
            # What the driver really gives (the service shows info.fps; warnings say what fell back).
            extra = {**self.info.extra, "fourcc": grabber.actual_fourcc, "warnings": list(grabber.warnings)}
            self.info = replace(self.info, fps=grabber.actual_fps, extra=extra, state="streaming")


def config_from_spec(spec: SourceSpec) -> StereoPairConfig:
    """StereoPairConfig from a ``v4l2:`` spec (see the module docstring for the options)."""
    return configs.from_spec(StereoPairConfig, spec)
