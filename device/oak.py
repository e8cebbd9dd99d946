"""Luxonis OAK cameras over DepthAI v3: colour CAM_A with stereo depth (CAM_B/CAM_C) aligned to it.

The device computes depth on board and aligns it to the colour camera; this module turns each
synchronised colour + depth pair into a :class:`measure.Frame` whose disparity is expressed at the
colour camera's focal length (ARCHITECTURE.md "Shared types": ``d = fx * B / Z - doffs``, doffs = 0).

The conversions are plain functions of DepthAI messages and calibration objects so that tests can
drive them with host-built ``dai.CalibrationHandler`` and ``dai.ImgFrame`` objects; only
:meth:`OakSource.open` needs a device.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, fields
from datetime import timedelta

# DepthAI prints a USB banner on import and searches 11 s for a device by default: keep the CLI
# quiet and make "no device" fail fast. Both must be set before the import.
os.environ.setdefault("DEPTHAI_LEVEL", "error")
os.environ.setdefault("DEPTHAI_SEARCH_TIMEOUT", "1000")

import cv2  # noqa: E402
import depthai as dai  # noqa: E402
import numpy as np  # noqa: E402

from measure import Frame, PinholeCamera  # noqa: E402

from .base import SourceBase, SourceInfo, SourceSpec, parse_flag  # noqa: E402
from .errors import CalibrationError, SourceDisconnected, SourceError, SourceNotFound, SourceTimeout  # noqa: E402

PRESETS: tuple[str, ...] = (
    "FAST_ACCURACY",
    "FAST_DENSITY",
    "DEFAULT",
    "FACE",
    "HIGH_DETAIL",
    "ROBOTICS",
    "DENSITY",
    "ACCURACY",
)
COLOR_SOCKET = dai.CameraBoardSocket.CAM_A
PLUG_IN_HINT = (
    "plug an OAK camera into a USB3 port (check with `depthruler devices`; in a container pass "
    "--device-cgroup-rule='c 189:* rmw' -v /dev/bus/usb:/dev/bus/usb), or use the simulator: "
    "`depthruler serve --source sim`"
)


@dataclass(frozen=True)
class OakConfig:
    """How to run an OAK: which device, colour output size and rate, and the stereo settings.

    ``confidence_threshold`` (0-255, lower keeps fewer pixels) overrides the preset's when set;
    ``search_timeout_ms`` bounds how long :meth:`OakSource.open` looks for the device.
    """

    mxid: str = ""
    fps: float = 15.0
    width: int = 1280
    height: int = 720
    mono_width: int = 640
    mono_height: int = 400
    preset: str = "DEFAULT"
    subpixel: bool = True
    lr_check: bool = True
    extended_disparity: bool = False
    confidence_threshold: int | None = None
    confidence_map: bool = True
    search_timeout_ms: int = 1000

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise SourceError(f"OAK preset {self.preset!r} is unknown; use one of {', '.join(PRESETS)}")
        if not (0 < self.fps <= 120):
            raise SourceError(f"OAK fps={self.fps} must lie in (0, 120]")
        for name in ("width", "height", "mono_width", "mono_height"):
            if getattr(self, name) < 16:
                raise SourceError(f"OAK {name}={getattr(self, name)} must be at least 16 pixels")
        if self.confidence_threshold is not None and not (0 <= self.confidence_threshold <= 255):
            raise SourceError(f"OAK confidence_threshold={self.confidence_threshold} must lie in 0..255")
        if not (100 <= self.search_timeout_ms <= 60_000):
            raise SourceError(f"OAK search_timeout_ms={self.search_timeout_ms} must lie in 100..60000")

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


def preset_mode(name: str) -> dai.node.StereoDepth.PresetMode:
    """The DepthAI v3 preset enum for a preset name (see :data:`PRESETS`)."""
    if name not in PRESETS:
        raise SourceError(f"OAK preset {name!r} is unknown; use one of {', '.join(PRESETS)}")
    return getattr(dai.node.StereoDepth.PresetMode, name)


def configure_stereo(stereo_config: dai.StereoDepthConfig, config: OakConfig) -> dai.StereoDepthConfig:
    """Apply the config's stereo settings to a ``StereoDepthConfig`` (a node's ``initialConfig``).

    Depth unit is forced to millimetres because :func:`depth_to_disparity` expects mm.
    """
    stereo_config.setLeftRightCheck(config.lr_check)
    stereo_config.setSubpixel(config.subpixel)
    stereo_config.setExtendedDisparity(config.extended_disparity)
    stereo_config.setDepthUnit(dai.LengthUnit.MILLIMETER)
    if config.confidence_threshold is not None:
        stereo_config.setConfidenceThreshold(config.confidence_threshold)
    return stereo_config


def intrinsics_from_calibration(
    calib: dai.CalibrationHandler, width: int, height: int, socket: dai.CameraBoardSocket = COLOR_SOCKET
) -> PinholeCamera:
    """The camera's pinhole intrinsics at an output size (pixels), from the device calibration.

    For an output with the calibrated aspect ratio this is a plain scaling of the stored matrix.
    For another aspect ratio DepthAI's fit may differ from the Camera node's resize mode, which is
    why :func:`camera_for_frame` prefers the transformation each device frame carries.
    """
    if not calib.hasCameraCalibration(socket):
        raise CalibrationError(f"the OAK has no calibration for {socket}; recalibrate it with Luxonis' tools")
    try:
        k = np.asarray(calib.getCameraIntrinsics(socket, width, height), dtype=np.float64)
    except RuntimeError as exc:
        raise CalibrationError(f"cannot read the intrinsics of {socket} from the OAK calibration: {exc}") from exc
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise CalibrationError(f"the OAK calibration of {socket} is not a valid camera matrix: {k.tolist()}")
    return PinholeCamera(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=width, height=height)


def baseline_m_from_calibration(calib: dai.CalibrationHandler) -> float:
    """The calibrated (not the board-design) stereo baseline in metres.

    ``getBaselineDistance`` answers in centimetres; ``useSpecTranslation=False`` takes the measured
    extrinsics rather than the nominal spacing of the board drawing.
    """
    try:
        left, right = calib.getStereoLeftCameraId(), calib.getStereoRightCameraId()
        baseline_cm = calib.getBaselineDistance(right, left, useSpecTranslation=False)
    except RuntimeError as exc:
        raise CalibrationError(f"the OAK calibration has no stereo extrinsics: {exc}") from exc
    if not np.isfinite(baseline_cm) or baseline_cm <= 0:
        raise CalibrationError(f"the OAK calibration gives a baseline of {baseline_cm} cm; recalibrate the device")
    return float(baseline_cm) / 100.0


def depth_to_disparity(depth_mm: np.ndarray, fx: float, baseline_m: float) -> np.ndarray:
    """Disparity (float32 pixels, NaN invalid) at focal length ``fx`` (pixels) from depth in mm.

    ``d = fx * B / Z`` (ARCHITECTURE.md, doffs = 0) with B in metres and Z = depth_mm / 1000;
    depth 0 is DepthAI's "no data".
    """
    z = np.asarray(depth_mm)
    if z.ndim != 2:
        raise SourceError(f"depth must be a 2-D array, got shape {z.shape}")
    out = np.full(z.shape, np.nan, dtype=np.float32)
    valid = z > 0
    out[valid] = (fx * baseline_m * 1000.0) / z[valid].astype(np.float64)
    return out


def confidence_from_map(conf_map: np.ndarray) -> np.ndarray:
    """DepthAI's confidence map (uint8, 0 = most confident, 255 = least) as float32 in [0, 1], 1 = best."""
    return (1.0 - np.asarray(conf_map, dtype=np.float32) / 255.0).astype(np.float32)


def camera_for_frame(rgb: dai.ImgFrame, fallback: PinholeCamera) -> PinholeCamera:
    """The intrinsics that apply to this colour frame.

    A device frame carries its own ``ImgTransformation`` (the crop/scale the ISP really applied);
    it wins when valid and of the frame's size. Otherwise the calibration-derived camera is used,
    scaled to the frame if the device delivered another size than requested.
    """
    w, h = rgb.getWidth(), rgb.getHeight()
    t = rgb.getTransformation()
    if t.isValid() and tuple(t.getSize()) == (w, h):
        k = np.asarray(t.getIntrinsicMatrix(), dtype=np.float64)
        if np.all(np.isfinite(k)) and k[0, 0] > 0 and k[1, 1] > 0:
            return PinholeCamera(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=w, height=h)
    if (w, h) != (fallback.width, fallback.height):
        return fallback.scaled(w, h)
    return fallback


def frame_from_messages(
    rgb: dai.ImgFrame,
    depth: dai.ImgFrame,
    conf: dai.ImgFrame | None,
    camera: PinholeCamera,
    baseline_m: float,
    meta: dict | None = None,
) -> Frame:
    """One :class:`Frame` from a synchronised colour frame and aligned depth (uint16 mm).

    Depth aligned by the device normally has the colour size; if not (RVC2 pads or scales on some
    configurations) it is resized with nearest neighbour so that no depth is invented between
    surfaces. Confidence is 0 where depth is invalid.
    """
    image = rgb.getCvFrame()
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    image = np.ascontiguousarray(image[:, :, :3], dtype=np.uint8)
    h, w = image.shape[:2]
    cam = camera_for_frame(rgb, camera)
    depth_mm = depth.getFrame()
    if depth_mm.dtype != np.uint16:
        raise SourceError(f"OAK depth must be uint16 millimetres (RAW16), got {depth_mm.dtype}")
    if depth_mm.shape != (h, w):
        depth_mm = cv2.resize(depth_mm, (w, h), interpolation=cv2.INTER_NEAREST)
    disparity = depth_to_disparity(depth_mm, cam.fx, baseline_m)
    confidence = None
    if conf is not None:
        c = conf.getFrame()
        if c.shape != (h, w):
            c = cv2.resize(c, (w, h), interpolation=cv2.INTER_NEAREST)
        confidence = confidence_from_map(c)
        confidence[np.isnan(disparity)] = 0.0
    stamp = rgb.getTimestampDevice() if rgb.getTimestampDevice() != timedelta(0) else rgb.getTimestamp()
    info = {"source": "oak", "sequence": int(rgb.getSequenceNum()), "depth_unit": "mm"}
    info.update(meta or {})
    return Frame(
        image=image,
        disparity=disparity,
        camera=cam,
        baseline_m=baseline_m,
        confidence=confidence,
        timestamp=stamp.total_seconds(),
        meta=info,
    )


def read_group(queue, timeout_s: float):
    """The next message of a DepthAI output queue, with DepthAI's failures mapped to typed errors.

    A closed queue (``MessageQueue.QueueException``) or an XLink ``RuntimeError`` means the device
    went away; no message within ``timeout_s`` is a timeout.
    """
    try:
        msg = queue.get(timedelta(seconds=timeout_s))
    except dai.MessageQueue.QueueException as exc:
        raise SourceDisconnected(f"the OAK stopped sending ({exc}); check the USB cable and reopen the source") from exc
    except RuntimeError as exc:
        raise SourceDisconnected(f"the OAK connection failed ({exc}); check the USB cable and reopen the source") from exc
    if msg is None:
        raise SourceTimeout(f"no frame from the OAK within {timeout_s:.1f} s; is the camera covered or overloaded?")
    return msg


def find_device(mxid: str, timeout_ms: int) -> dai.DeviceInfo:
    """The DeviceInfo of an attached OAK (a given mxid, or any), polling until ``timeout_ms``."""
    deadline = time.monotonic() + timeout_ms / 1000.0
    seen: list[str] = []
    while True:
        try:
            infos = dai.Device.getAllAvailableDevices()
        except RuntimeError as exc:
            raise SourceNotFound(f"DepthAI cannot search for devices ({exc}); {PLUG_IN_HINT}") from exc
        seen = [i.getDeviceId() for i in infos]
        for info in infos:
            if not mxid or info.getDeviceId() == mxid or info.name == mxid:
                return info
        if time.monotonic() >= deadline:
            break
        time.sleep(0.1)
    try:
        busy = [i.getDeviceId() for i in dai.Device.getAllConnectedDevices()
                if not mxid or i.getDeviceId() == mxid or i.name == mxid]
    except RuntimeError:
        busy = []
    if busy:
        raise SourceNotFound(f"OAK {busy[0]} is connected but in use by another program; close that program "
                             "(or the other depthruler) and retry")
    if mxid and seen:
        raise SourceNotFound(f"no OAK with id {mxid!r}; attached: {', '.join(seen)}. Use 'oak:<one of those>'")
    what = f"OAK {mxid!r}" if mxid else "OAK camera"
    raise SourceNotFound(f"no {what} found within {timeout_ms / 1000:.1f} s; {PLUG_IN_HINT}")


class OakSource(SourceBase):
    """Colour + aligned stereo depth from an OAK, as Frames. ``with OakSource(OakConfig()) as s: s.read()``."""

    def __init__(self, config: OakConfig = OakConfig()) -> None:
        self.config = config
        self.info = SourceInfo(
            kind="oak", name="OAK", serial=config.mxid, width=config.width, height=config.height, fps=config.fps
        )
        self._pipeline = None
        self._device = None
        self._queue = None
        self._camera: PinholeCamera | None = None
        self._baseline_m = 0.0

    def open(self) -> None:
        if self.is_open:
            return
        cfg = self.config
        info = find_device(cfg.mxid, cfg.search_timeout_ms)
        try:
            self._device = dai.Device(info)
            calib = self._device.readCalibration()
            self._camera = intrinsics_from_calibration(calib, cfg.width, cfg.height)
            self._baseline_m = baseline_m_from_calibration(calib)
            self._pipeline = dai.Pipeline(self._device)
            self._queue = self._build(self._pipeline, self._device.getPlatform())
            self._pipeline.start()
        except SourceError:
            self._release()
            raise
        except RuntimeError as exc:
            self._release()
            raise SourceNotFound(f"the OAK {info.getDeviceId()} was found but cannot be started ({exc}); "
                                 "unplug and replug it, or close other programs using it") from exc
        self.info = SourceInfo(
            kind="oak",
            name=f"OAK {self._device.getDeviceName()}",
            serial=info.getDeviceId(),
            width=cfg.width,
            height=cfg.height,
            fps=cfg.fps,
            state="streaming",
            extra={"platform": self._device.getPlatformAsString(), "preset": cfg.preset},
        )
        super().open()

    def _build(self, pipeline: dai.Pipeline, platform: dai.Platform):
        cfg = self.config
        color = pipeline.create(dai.node.Camera).build(COLOR_SOCKET)
        left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
        right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
        # Undistorted colour so the pinhole intrinsics hold across the image.
        color_out = color.requestOutput(cfg.size, fps=cfg.fps, enableUndistortion=True)
        mono = (cfg.mono_width, cfg.mono_height)
        stereo = pipeline.create(dai.node.StereoDepth).build(
            left.requestOutput(mono, fps=cfg.fps), right.requestOutput(mono, fps=cfg.fps), preset_mode(cfg.preset)
        )
        stereo.setLeftRightCheck(cfg.lr_check)
        stereo.setSubpixel(cfg.subpixel)
        stereo.setExtendedDisparity(cfg.extended_disparity)
        stereo.setDisparityToDepthUseSpecTranslation(False)
        configure_stereo(stereo.initialConfig, cfg)
        sync = pipeline.create(dai.node.Sync)
        sync.setSyncThreshold(timedelta(seconds=0.5 / cfg.fps))
        color_out.link(sync.inputs["rgb"])
        if platform == dai.Platform.RVC4:
            align = pipeline.create(dai.node.ImageAlign)
            stereo.depth.link(align.input)
            color_out.link(align.inputAlignTo)
            align.outputAligned.link(sync.inputs["depth"])
            if cfg.confidence_map:
                conf_align = pipeline.create(dai.node.ImageAlign)
                stereo.confidenceMap.link(conf_align.input)
                color_out.link(conf_align.inputAlignTo)
                conf_align.outputAligned.link(sync.inputs["conf"])
        else:
            # RVC2 aligns inside StereoDepth; its confidence map stays in the rectified mono frame,
            # so it cannot be registered to colour and is not delivered.
            color_out.link(stereo.inputAlignTo)
            stereo.depth.link(sync.inputs["depth"])
        queue = sync.out.createOutputQueue(maxSize=4, blocking=False)
        return queue

    def read(self, timeout_s: float = 1.0) -> Frame:
        if not self.is_open or self._queue is None or self._camera is None:
            raise SourceError("the OAK source is not open; call open() or use `with open_source('oak') as src:`")
        group = read_group(self._queue, timeout_s)
        names = set(group.getMessageNames())
        conf = group["conf"] if "conf" in names else None
        return frame_from_messages(
            group["rgb"], group["depth"], conf, self._camera, self._baseline_m, {"serial": self.info.serial}
        )

    def _release(self) -> None:
        pipeline, device = self._pipeline, self._device
        self._pipeline = self._device = self._queue = None
        for obj, stop in ((pipeline, "stop"), (device, "close")):
            if obj is not None:
                try:
                    getattr(obj, stop)()
                except RuntimeError:
                    pass  # already gone (cable pulled): nothing left to release

    def close(self) -> None:
        self._release()
        super().close()




def config_from_spec(spec: SourceSpec) -> OakConfig:
    """OakConfig from ``oak[:<mxid>][?preset=HIGH_DETAIL&fps=10&size=1280x720&subpixel=1&lr_check=1
    &extended_disparity=0&confidence_threshold=200&confidence_map=1&search_timeout_ms=2000]``."""
    known = {f.name for f in fields(OakConfig)} - {"mxid", "width", "height"}
    kwargs: dict = {"mxid": spec.target}
    for key, value in spec.params.items():
        try:
            if key == "size":
                w, _, h = value.lower().partition("x")
                kwargs["width"], kwargs["height"] = int(w), int(h)
            elif key == "preset":
                kwargs["preset"] = value.upper()
            elif key in ("subpixel", "lr_check", "extended_disparity", "confidence_map"):
                kwargs[key] = parse_flag(value)
            elif key == "fps":
                kwargs["fps"] = float(value)
            elif key in ("confidence_threshold", "search_timeout_ms", "mono_width", "mono_height"):
                kwargs[key] = int(value)
            else:
                raise SourceError(
                    f"unknown OAK option {key!r} in {str(spec)!r}; use: size, {', '.join(sorted(known))}"
                )
        except (ValueError, KeyError) as exc:
            raise SourceError(f"OAK option {key}={value!r} in {str(spec)!r} is not valid") from exc
    return OakConfig(**kwargs)


def from_spec(spec: SourceSpec) -> OakSource:
    """An unopened OakSource for ``oak`` or ``oak:<mxid>?preset=...&fps=...``."""
    return OakSource(config_from_spec(spec))
