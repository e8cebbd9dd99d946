"""A V4L2 stereo pair (one side-by-side UVC camera or two nodes) with OpenCV SGBM, as Frames.

Capture and processing are separate so tests drive the real processing with recorded or
rendered pairs: a :class:`FrameGrabber` yields (left, right, timestamp) — :class:`V4L2Grabber`
from cameras (any ``cv2.VideoCapture``-like object can be injected), :class:`ImagePairGrabber`
from memory, ``device.sources.video.VideoGrabber`` from files — and :class:`StereoProcessor` turns a pair
into a :class:`measure.Frame`: rectification from the calibration (device/calibration/stereo.py,
device/calibration/files.py), SGBM (device/sources/sgbm.py), output registered to the *rectified left*
colour image. :class:`ProcessedPairSource` is grabber + calibration + processor for every such source.

Spec: ``v4l2:/dev/video0?layout=side-by-side&calib=FILE[&calib_units=mm&distortion=opencv|equidistant
&size=1280x480&fps=30&fourcc=MJPG&mode=sgbm_3way&ndisp=64&block=5&wls=0&lr_confidence=1&fill_left_band=1
&scale=1]`` or ``v4l2:/dev/video0,/dev/video2?calib=...`` (size is per node: both halves together for a
side-by-side camera). ``calib`` is the project's JSON, an OpenCV YAML/XML or a ROS ``left.yaml,right.yaml``.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from measure import Frame, MeasureError, PinholeCamera

from device.base import SourceBase, SourceInfo, SourceSpec, parse_flag
from device.calibration.stereo import StereoCalibration
from device.calibration.files import CalibrationRef
from device.errors import CalibrationError, SourceDisconnected, SourceEnded, SourceError, SourceNotFound, SourceTimeout
from device.sources.sgbm import MODES, SGBMConfig, compute_disparity

log = logging.getLogger(__name__)
LAYOUTS = ("side-by-side", "two-nodes")
NO_CAMERA_HINT = (
    "plug in the stereo camera and check `depthruler devices` (or `v4l2-ctl --list-devices`); "
    "in a container pass --device /dev/videoN; or use the simulator: `depthruler serve --source sim`"
)


class FrameGrabber(Protocol):
    """Where stereo pairs come from: cameras, files or memory. ``grab`` returns BGR left, right, seconds."""

    def open(self) -> None: ...

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class StereoPairConfig:
    """Capture settings (per V4L2 node), calibration file and SGBM settings of a stereo pair.

    Defaults give 640x480 per eye with SGBM_3WAY, no WLS, no right matcher: the configuration
    that keeps live view at >= 10 fps on a 2-core machine (bench/RESULTS.md "## SGBM"; 1280x720
    eyes run at about half that). ``scale`` < 1 runs rectification and SGBM on a downscaled pair
    (faster live view; the intrinsics are scaled with it). ``max_skew_s`` bounds the timestamp gap
    of a two-node pair (default: half a frame period).
    """

    devices: tuple[str, ...] = ("/dev/video0",)
    layout: str = "side-by-side"
    fourcc: str = "MJPG"
    width: int = 1280
    height: int = 480
    fps: float = 30.0
    calibration: CalibrationRef = field(default_factory=lambda: CalibrationRef(""))
    sgbm: SGBMConfig = field(default_factory=SGBMConfig)
    scale: float = 1.0
    max_skew_s: float | None = None

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise SourceError(f"layout {self.layout!r} is unknown; use one of {', '.join(LAYOUTS)}")
        want = 1 if self.layout == "side-by-side" else 2
        if len(self.devices) != want:
            raise SourceError(
                f"layout {self.layout} needs {want} device node(s), got {len(self.devices)}: {', '.join(self.devices)}"
            )
        if len(self.fourcc) != 4:
            raise SourceError(f"fourcc {self.fourcc!r} must have four characters, e.g. MJPG or YUYV")
        if self.width < 16 or self.height < 16 or (self.layout == "side-by-side" and self.width % 2):
            raise SourceError(f"size {self.width}x{self.height} is not valid (side-by-side needs an even width)")
        if not (0 < self.fps <= 240):
            raise SourceError(f"fps={self.fps} must lie in (0, 240]")
        if not (0.1 <= self.scale <= 1.0):
            raise SourceError(f"scale={self.scale} must lie in [0.1, 1]")

    @property
    def eye_size(self) -> tuple[int, int]:
        """Size of one camera's image as captured."""
        if self.layout == "side-by-side":
            return (self.width // 2, self.height)
        return (self.width, self.height)


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


@dataclass(frozen=True)
class Rectification:
    """Rectification maps of a calibrated pair at one image size, and the rectified left camera.

    ``baseline_m`` and ``doffs`` give ``Z = fx * B / (d + doffs)`` for disparities measured
    between the rectified images (doffs is the principal point gap cx_right - cx_left).
    """

    size: tuple[int, int]
    camera: PinholeCamera
    baseline_m: float
    doffs: float
    maps: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None  # None: already rectified


def rectification(calib: StereoCalibration, size: tuple[int, int]) -> Rectification:
    """Rectification for images of ``size`` (w, h): ``cv2.stereoRectify`` + ``initUndistortRectifyMap``.

    Intrinsics are scaled when the images have another size than at calibration (same aspect only).
    ``calib.extra["rectified"]`` marks a pair that is already rectified (a dataset, or a camera that
    rectifies on board): the images are used as they are, with K1's intrinsics and ``|T|``.
    """
    import cv2

    cw, ch = calib.image_size
    w, h = size
    if abs(w / cw - h / ch) > 1e-3 * max(w / cw, h / ch):
        raise CalibrationError(
            f"images are {w}x{h} but the calibration was made at {cw}x{ch} (another aspect ratio); "
            "capture at the calibrated size or recalibrate"
        )
    s = w / cw
    scale = np.array([[s, 0, (s - 1) * 0.5], [0, s, (s - 1) * 0.5], [0, 0, 1]])  # pixel-centre convention
    K1, K2 = scale @ calib.K1, scale @ calib.K2
    if calib.extra.get("rectified"):
        cam = _camera(K1, w, h)
        return Rectification(size, cam, calib.baseline_m, float(K2[0, 2] - K1[0, 2]), None)
    T = np.asarray(calib.T, np.float64).reshape(3, 1)  # OpenCV 5 asserts on any other shape
    if abs(T[0, 0]) < np.abs(T[1:, 0]).max():
        raise CalibrationError(f"T = {T.ravel().tolist()} m is not a side-by-side pair (x must dominate); "
                               "mount the cameras horizontally and recalibrate")
    if T[0, 0] > 0:
        raise CalibrationError("the calibration puts the right camera to the left of the left one (T_x > 0); "
                               "swap the left and right images (or devices) and recalibrate")
    undistort: Callable[..., tuple[np.ndarray, np.ndarray]]
    if calib.distortion_model == "equidistant":
        # OpenCV's fisheye model (Kalibr's "equidistant"); balance 0 crops to valid pixels like alpha 0.
        R1, R2, P1, P2, _Q = cv2.fisheye.stereoRectify(
            K1, calib.D1, K2, calib.D2, (w, h), calib.R, T, cv2.CALIB_ZERO_DISPARITY, balance=0.0
        )
        undistort = cv2.fisheye.initUndistortRectifyMap
    else:
        R1, R2, P1, P2, _Q, _roi1, _roi2 = cv2.stereoRectify(
            K1, calib.D1, K2, calib.D2, (w, h), calib.R, T, flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
        )
        undistort = cv2.initUndistortRectifyMap
    maps = (
        *undistort(K1, calib.D1, R1, P1, (w, h), cv2.CV_32FC1),
        *undistort(K2, calib.D2, R2, P2, (w, h), cv2.CV_32FC1),
    )
    cam = _camera(P1, w, h)
    baseline = float(-P2[0, 3] / P2[0, 0])
    if not (math.isfinite(baseline) and baseline > 0 and np.isfinite(P2[:, :3]).all()):
        raise CalibrationError(f"rectifying this calibration gives no usable right camera (baseline {baseline:g} m); "
                               "its D2, R or T are implausible: recalibrate")
    return Rectification(size, cam, baseline, float(P2[0, 2] - P1[0, 2]), maps)


def _camera(K: np.ndarray, w: int, h: int) -> PinholeCamera:
    """The rectified left camera, or CalibrationError when the calibration's numbers give none in range."""
    try:
        return PinholeCamera(fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]), width=w, height=h)
    except MeasureError as exc:
        raise CalibrationError(f"rectifying this calibration gives no usable camera ({exc}); "
                               "its distortion coefficients or R are implausible: recalibrate") from None


class StereoProcessor:
    """Rectify a pair, run SGBM, and return the Frame registered to the rectified left image."""

    def __init__(self, calibration: StereoCalibration, sgbm: SGBMConfig = SGBMConfig(), scale: float = 1.0) -> None:
        self.calibration = calibration
        self.sgbm = sgbm
        self.scale = scale
        self._rect: Rectification | None = None

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, Rectification]:
        import cv2

        if left.shape != right.shape:
            raise SourceError(f"left image is {left.shape} but right is {right.shape}; both cameras must use one size")
        if self.scale != 1.0:
            size = (round(left.shape[1] * self.scale), round(left.shape[0] * self.scale))
            left = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
            right = cv2.resize(right, size, interpolation=cv2.INTER_AREA)
        size = (left.shape[1], left.shape[0])
        if self._rect is None or self._rect.size != size:
            self._rect = rectification(self.calibration, size)
        rect = self._rect
        if rect.maps is None:
            return left, right, rect
        m1x, m1y, m2x, m2y = rect.maps
        return (
            cv2.remap(left, m1x, m1y, cv2.INTER_LINEAR),
            cv2.remap(right, m2x, m2y, cv2.INTER_LINEAR),
            rect,
        )

    def process(self, left: np.ndarray, right: np.ndarray, timestamp: float = 0.0, meta: dict | None = None) -> Frame:
        """Frame from one raw (unrectified) pair of BGR uint8 images."""
        import cv2

        if left.ndim == 2:
            left, right = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)
        left_r, right_r, rect = self.rectify(left, right)
        disparity, confidence = compute_disparity(left_r, right_r, self.sgbm)
        info = {"source": "v4l2", "rectified": rect.maps is not None, "sgbm_mode": self.sgbm.mode}
        info.update(meta or {})
        return Frame(
            image=np.ascontiguousarray(left_r),
            disparity=disparity.astype(np.float32, copy=False),
            camera=rect.camera,
            baseline_m=rect.baseline_m,
            doffs=rect.doffs,
            confidence=confidence.astype(np.float32, copy=False),
            timestamp=timestamp,
            meta=info,
        )


class ProcessedPairSource(SourceBase):
    """Pairs from a grabber (cameras, video files, memory) through calibration + :class:`StereoProcessor`.

    Every stereo source without on-board depth is this class with another grabber, so a video file
    and a live pair are rectified and matched by the very same code.
    """

    def __init__(
        self,
        grabber: FrameGrabber,
        calib: CalibrationRef | StereoCalibration,
        sgbm: SGBMConfig,
        scale: float,
        info: SourceInfo,
        meta: dict | None = None,
    ) -> None:
        self.grabber = grabber
        self._calib = calib
        self.sgbm = sgbm
        self.scale = scale
        self.info = info
        self._meta = dict(meta or {})
        self._processor: StereoProcessor | None = None

    def open(self) -> None:
        if self.is_open:
            return
        # The camera (or file) first: if it is not there, that is the first thing to fix.
        self.grabber.open()
        try:
            calib = self._calib if isinstance(self._calib, StereoCalibration) else self._calib.load()
            self._processor = StereoProcessor(calib, self.sgbm, self.scale)
        except Exception:
            self.grabber.close()
            raise
        super().open()

    def read(self, timeout_s: float = 1.0) -> Frame:
        if not self.is_open or self._processor is None:
            raise SourceError(f"the {self.info.kind} source is not open; call open() or use `with open_source(spec) as src:`")
        left, right, stamp = self.grabber.grab(timeout_s)
        return self._processor.process(left, right, stamp, self._meta)

    def close(self) -> None:
        self.grabber.close()
        super().close()


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


_SGBM_KEYS = {"mode": "mode", "ndisp": "num_disparities", "block": "block_size", "p1": "p1", "p2": "p2",
              "uniqueness": "uniqueness", "wls": "wls", "wls_lambda": "wls_lambda", "wls_sigma": "wls_sigma",
              "lr_confidence": "lr_confidence", "speckle_window": "speckle_window", "speckle_range": "speckle_range",
              "fill_left_band": "fill_left_band"}
CALIB_KEYS = ("calib", "calib_units", "distortion")
SGBM_OPTIONS = tuple(_SGBM_KEYS)


def sgbm_from_params(params: dict[str, str], spec: SourceSpec) -> SGBMConfig:
    """The SGBMConfig of a spec's SGBM options (``ndisp``, ``block``, ``mode``, ...); others are ignored."""
    sgbm: dict = {}
    sgbm_types = {f.name: str(f.type) for f in fields(SGBMConfig)}
    for key, value in params.items():
        if key not in _SGBM_KEYS:
            continue
        name = _SGBM_KEYS[key]
        kind = sgbm_types[name]
        try:
            sgbm[name] = (parse_flag(value) if "bool" in kind else value if name == "mode"
                          else float(value) if "float" in kind else int(value))
        except ValueError as exc:
            raise SourceError(f"{spec.kind} option {key}={value!r} in {str(spec)!r} is not valid") from exc
    if "mode" in sgbm and sgbm["mode"] not in MODES:
        raise SourceError(f"SGBM mode {sgbm['mode']!r} is unknown; use one of {', '.join(MODES)}")
    try:
        return SGBMConfig(**sgbm)
    except ValueError as exc:
        raise SourceError(f"SGBM options in {str(spec)!r}: {exc}") from exc


def calibration_from_params(params: dict[str, str]) -> CalibrationRef:
    """The calibration a spec names: ``calib=FILE`` (or ``calib=LEFT.yaml,RIGHT.yaml`` for ROS),
    ``calib_units=m|mm`` (unit of T in OpenCV/ROS files) and ``distortion=opencv|equidistant``."""
    return CalibrationRef(params.get("calib", ""), params.get("calib_units", "m"), params.get("distortion") or None)


def config_from_spec(spec: SourceSpec) -> StereoPairConfig:
    """StereoPairConfig from a ``v4l2:`` spec (see the module docstring for the options)."""
    devices = tuple(d.strip() for d in spec.target.split(",") if d.strip()) or ("/dev/video0",)
    kwargs: dict = {"devices": devices, "layout": "side-by-side" if len(devices) == 1 else "two-nodes"}
    for key, value in spec.params.items():
        try:
            if key == "size":
                w, _, h = value.lower().partition("x")
                kwargs["width"], kwargs["height"] = int(w), int(h)
            elif key in ("layout", "fourcc"):
                kwargs[key] = value if key == "layout" else value.upper()
            elif key in ("fps", "scale", "max_skew_s"):
                kwargs[key] = float(value)
            elif key not in _SGBM_KEYS and key not in CALIB_KEYS:
                raise SourceError(
                    f"unknown v4l2 option {key!r} in {str(spec)!r}; use: size, layout, fourcc, fps, scale, "
                    f"max_skew_s, {', '.join(CALIB_KEYS)}, {', '.join(_SGBM_KEYS)}"
                )
        except (ValueError, KeyError) as exc:
            raise SourceError(f"v4l2 option {key}={value!r} in {str(spec)!r} is not valid") from exc
    if kwargs["layout"] == "two-nodes" and "size" not in spec.params:
        kwargs["width"], kwargs["height"] = 640, 480
    kwargs["sgbm"] = sgbm_from_params(spec.params, spec)
    kwargs["calibration"] = calibration_from_params(spec.params)
    return StereoPairConfig(**kwargs)

