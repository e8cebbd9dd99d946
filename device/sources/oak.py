"""Luxonis OAK cameras over DepthAI v3: stereo depth aligned to the colour camera (or the left mono).

The device computes depth on board and aligns it to the output image; this module turns each
synchronised image + depth pair into a :class:`measure.Frame` whose disparity is expressed at the
output camera's focal length (docs/design.md "Shared types": ``d = fx * B / Z - doffs``, doffs = 0).

DepthAI v3 semantics this module relies on (checked against the 3.12 stubs and depthai-core's v3
examples; verified without hardware only):

- sockets come from the device (``getConnectedCameraFeatures``) and the stereo pair from its
  calibration (``getStereoLeftCameraId``), not fixed CAM_A/B/C: a model without a colour camera
  delivers the rectified left image with depth aligned to it (:func:`choose_sockets`);
- the confidence map is 255 = most confident and ``setConfidenceThreshold(t)`` keeps pixels whose
  confidence is above ``t`` (default 55). It is delivered only when it is registered to the image:
  aligned to the rectified left (``align=left``). DepthAI cannot align it to colour (RVC2 leaves it
  in the rectified frame; RVC4's ImageAlign warps a RAW8 map without any depth-dependent shift);
- ``StereoDepth.build(..., preset)`` applies the preset; only options the user set override it;
- the pipeline's automatic calibration (ON_START by default in 3.12, may write a calibration to the
  device) is OFF unless ``auto_calibration=on_start|continuous`` is asked for;
- the output queue holds one message and drops older ones (newest wins: no queued latency), and
  ``Frame.timestamp`` is the host-synced ``getTimestamp`` (host monotonic clock), not the device clock.

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

from device.base import SourceBase, SourceInfo, SourceSpec, parse_flag  # noqa: E402
from device.discovery import OAK_UDEV_RULE, list_usb  # noqa: E402
from device.errors import CalibrationError, SourceDisconnected, SourceError, SourceNotFound, SourceTimeout  # noqa: E402

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
ALIGNS: tuple[str, ...] = ("auto", "color", "left")
AUTO_CALIBRATION = {
    "off": dai.Pipeline.AutoCalibrationMode.OFF,
    "on_start": dai.Pipeline.AutoCalibrationMode.ON_START,
    "continuous": dai.Pipeline.AutoCalibrationMode.CONTINUOUS,
}
COLOR_SOCKET = dai.CameraBoardSocket.CAM_A
UDEV_RULE = OAK_UDEV_RULE
UDEV_HINT = (
    "this user may not open the OAK's USB device: install the udev rule with\n"
    f"  echo '{UDEV_RULE}' | sudo tee /etc/udev/rules.d/80-movidius.rules\n"
    "  sudo udevadm control --reload-rules && sudo udevadm trigger\n"
    "then unplug and replug the OAK (in a container also pass --device-cgroup-rule='c 189:* rmw' "
    "-v /dev/bus/usb:/dev/bus/usb)"
)
PLUG_IN_HINT = (
    "plug an OAK camera into a USB3 port (check with `depthruler devices`; in a container pass "
    "--device-cgroup-rule='c 189:* rmw' -v /dev/bus/usb:/dev/bus/usb), or use the simulator: "
    "`depthruler serve --source sim`"
)


@dataclass(frozen=True)
class OakConfig:
    """How to run an OAK: which device, output size and rate, and the stereo settings.

    ``subpixel``, ``lr_check``, ``extended_disparity`` and ``confidence_threshold`` are None
    ("as the preset says") unless set. ``confidence_threshold`` has DepthAI v3's meaning: 0-255,
    pixels whose confidence (255 = best) is above it are kept, so a *higher* value keeps *fewer*
    pixels (v2 had the opposite scale: a v2 value of 200-245 would drop most depth in v3).
    ``align``: "color" (depth on the colour image), "left" (the rectified left mono image, with the
    confidence map) or "auto" (colour when the device has a colour camera). ``auto_calibration``:
    DepthAI's automatic recalibration, "off" (default), "on_start" or "continuous" (may write a
    new calibration to the device). ``search_timeout_ms`` bounds how long
    :meth:`OakSource.open` looks for the device.
    """

    mxid: str = ""
    fps: float = 15.0
    width: int = 1280
    height: int = 720
    mono_width: int = 640
    mono_height: int = 400
    preset: str = "DEFAULT"
    subpixel: bool | None = None
    lr_check: bool | None = None
    extended_disparity: bool | None = None
    confidence_threshold: int | None = None
    confidence_map: bool = True
    align: str = "auto"
    auto_calibration: str = "off"
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
        if self.align not in ALIGNS:
            raise SourceError(f"OAK align={self.align!r} is unknown; use one of {', '.join(ALIGNS)}")
        if self.auto_calibration not in AUTO_CALIBRATION:
            raise SourceError(f"OAK auto_calibration={self.auto_calibration!r} is unknown; "
                              f"use one of {', '.join(AUTO_CALIBRATION)}")
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
    """Apply the stereo settings the user set to a ``StereoDepthConfig`` (a node's ``initialConfig``,
    which ``StereoDepth.build(..., preset)`` has already filled from the preset): an option left at
    None keeps the preset's value. Depth unit is forced to millimetres because
    :func:`depth_to_disparity` expects mm.
    """
    if config.lr_check is not None:
        stereo_config.setLeftRightCheck(config.lr_check)
    if config.subpixel is not None:
        stereo_config.setSubpixel(config.subpixel)
    if config.extended_disparity is not None:
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

    ``d = fx * B / Z`` (docs/design.md, doffs = 0) with B in metres and Z = depth_mm / 1000;
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
    """DepthAI v3's confidence map (uint8, 255 = most confident, 0 = least) as float32 in [0, 1], 1 = best.

    v2 had the inverse scale (0 = best); since v3 ``setConfidenceThreshold`` keeps values above it.
    """
    return (np.asarray(conf_map, dtype=np.float32) / 255.0).astype(np.float32)


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
    # Host-synced time (DepthAI maps the device clock onto the host's steady clock), so frames of
    # several devices and host events share one time base; the device clock restarts at boot.
    stamp = rgb.getTimestamp()
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


def read_group(queue: dai.MessageQueue, timeout_s: float, device: dai.Device | None = None) -> dai.MessageGroup:
    """The next message of a DepthAI output queue, with DepthAI's failures mapped to typed errors.

    A closed queue (``MessageQueue.QueueException``), an XLink ``RuntimeError`` or, after a wait
    without message, a closed device means the device went away (:class:`SourceDisconnected`:
    reopen). No message within ``timeout_s`` from a device that is still there is a
    :class:`SourceTimeout` (covered lens, overloaded bus: wait, do not reboot the device).
    """
    try:
        msg = queue.get(timedelta(seconds=timeout_s))
    except dai.MessageQueue.QueueException as exc:
        raise SourceDisconnected(f"the OAK stopped sending ({exc}); check the USB cable and reopen the source") from exc
    except RuntimeError as exc:
        raise SourceDisconnected(f"the OAK connection failed ({exc}); check the USB cable and reopen the source") from exc
    if msg is None:
        if queue.isClosed() or (device is not None and device.isClosed()):
            raise SourceDisconnected("the OAK closed its connection (unplugged or crashed); check the USB "
                                     "cable and reopen the source")
        raise SourceTimeout(f"no frame from the OAK within {timeout_s:.1f} s; it is still connected: is it "
                            "overloaded (lower fps or size) or is the USB link saturated?")
    if not isinstance(msg, dai.MessageGroup):
        raise SourceError(f"the OAK pipeline sent a {type(msg).__name__}, expected a synchronised MessageGroup")
    return msg


def _matches(info: dai.DeviceInfo, mxid: str) -> bool:
    return not mxid or info.getDeviceId() == mxid or info.name == mxid


def find_device(mxid: str, timeout_ms: int) -> dai.DeviceInfo:
    """The DeviceInfo of an attached OAK (a given mxid, or any), polling until ``timeout_ms``.

    When none is available, every connected device is listed *including invalid ones*
    (``skipInvalidDevices=False``): a device this user may not open reports
    ``X_LINK_INSUFFICIENT_PERMISSIONS`` and the error prints the udev rule to install.
    """
    deadline = time.monotonic() + timeout_ms / 1000.0
    seen: list[str] = []
    while True:
        try:
            infos = dai.Device.getAllAvailableDevices()
        except RuntimeError as exc:
            raise SourceNotFound(f"DepthAI cannot search for devices ({exc}); {PLUG_IN_HINT}") from exc
        seen = [i.getDeviceId() for i in infos]
        for info in infos:
            if _matches(info, mxid):
                return info
        if time.monotonic() >= deadline:
            break
        time.sleep(0.1)
    try:
        connected = [i for i in dai.XLinkConnection.getAllConnectedDevices(skipInvalidDevices=False)
                     if _matches(i, mxid)]
    except RuntimeError:
        connected = []
    denied = [i for i in connected if i.status == dai.XLinkError_t.X_LINK_INSUFFICIENT_PERMISSIONS]
    if denied:
        who = denied[0].getDeviceId() or denied[0].name
        raise SourceNotFound(f"an OAK ({who}) is connected but {UDEV_HINT}")
    busy = [i.getDeviceId() for i in connected if i.state == dai.XLinkDeviceState.X_LINK_BOOTED]
    if busy:
        raise SourceNotFound(f"OAK {busy[0]} is connected but in use by another program; close that program "
                             "(or the other depthruler) and retry")
    if mxid and seen:
        raise SourceNotFound(f"no OAK with id {mxid!r}; attached: {', '.join(seen)}. Use 'oak:<one of those>'")
    # XLink saw nothing, but the USB bus may still hold an OAK this user cannot open (what lsusb shows).
    on_usb = [d for d in list_usb() if str(d.extra.get("usb_id", "")).startswith("03e7:")]
    if on_usb and not seen:
        raise SourceNotFound(f"the USB bus has an OAK ({on_usb[0].extra['usb_id']}, {on_usb[0].state}) that DepthAI "
                             f"cannot open; {UDEV_HINT}")
    what = f"OAK {mxid!r}" if mxid else "OAK camera"
    raise SourceNotFound(f"no {what} found within {timeout_ms / 1000:.1f} s; {PLUG_IN_HINT}")


@dataclass(frozen=True)
class Sockets:
    """Which cameras of the device to use: the stereo pair and the camera depth is aligned to
    (``color`` None: the rectified left mono image is the output)."""

    left: dai.CameraBoardSocket
    right: dai.CameraBoardSocket
    color: dai.CameraBoardSocket | None


def choose_sockets(features: list[dai.CameraFeatures], calib: dai.CalibrationHandler, align: str = "auto") -> Sockets:
    """The stereo pair and the output camera of a device, from what it reports.

    The stereo pair is the calibration's stereo left/right when both are connected (an OAK-D-LR
    pairs two colour sensors), else the two connected mono cameras. The output is CAM_A when it is
    a connected colour camera outside the pair, else any such colour camera, else (or with
    ``align="left"``) the rectified left image.
    """
    connected = {f.socket: f for f in features}
    pair: tuple[dai.CameraBoardSocket, dai.CameraBoardSocket] | None = None
    try:
        ids = (calib.getStereoLeftCameraId(), calib.getStereoRightCameraId())
        if ids[0] != ids[1] and all(i in connected for i in ids):
            pair = ids
    except RuntimeError:
        pass  # no stereo extrinsics in the calibration: fall back to the mono cameras
    if pair is None:
        monos = sorted((s for s, f in connected.items() if dai.CameraSensorType.MONO in f.supportedTypes), key=int)
        if len(monos) < 2:
            raise SourceNotFound(
                f"this OAK has no stereo pair (cameras: {', '.join(f'{s.name} {connected[s].sensorName}' for s in connected)}); "
                "depthruler needs an OAK-D model"
            )
        pair = (monos[0], monos[1])
    colours = [s for s, f in connected.items() if dai.CameraSensorType.COLOR in f.supportedTypes and s not in pair]
    if align == "color" and not colours:
        raise SourceError("align=color was asked but this OAK has no colour camera outside its stereo pair; "
                          "use align=left (or auto)")
    color = None
    if align != "left" and colours:
        color = COLOR_SOCKET if COLOR_SOCKET in colours else sorted(colours, key=int)[0]
    return Sockets(left=pair[0], right=pair[1], color=color)


class OakSource(SourceBase):
    """Aligned image + stereo depth from an OAK, as Frames. ``with OakSource(OakConfig()) as s: s.read()``."""

    def __init__(self, config: OakConfig = OakConfig()) -> None:
        self.config = config
        self.info = SourceInfo(
            kind="oak", name="OAK", serial=config.mxid, width=config.width, height=config.height, fps=config.fps
        )
        self._pipeline: dai.Pipeline | None = None
        self._device: dai.Device | None = None
        self._queue: dai.MessageQueue | None = None
        self._camera: PinholeCamera | None = None
        self._baseline_m = 0.0

    def open(self) -> None:
        if self.is_open:
            return
        cfg = self.config
        info = find_device(cfg.mxid, cfg.search_timeout_ms)
        try:
            device = self._device = dai.Device(info)
            calib = device.readCalibration()
            sockets = choose_sockets(device.getConnectedCameraFeatures(), calib, cfg.align)
            self._camera = output_camera(calib, sockets, cfg)
            self._baseline_m = baseline_m_from_calibration(calib)
            pipeline = self._pipeline = dai.Pipeline(device)
            self._queue = self._build(pipeline, device.getPlatform(), sockets)
            pipeline.start()
        except SourceError:
            self._release()
            raise
        except RuntimeError as exc:
            self._release()
            raise SourceNotFound(f"the OAK {info.getDeviceId()} was found but cannot be started ({exc}); "
                                 "unplug and replug it, or close other programs using it") from exc
        w, h = (cfg.width, cfg.height) if sockets.color is not None else (cfg.mono_width, cfg.mono_height)
        self.info = SourceInfo(
            kind="oak",
            name=f"OAK {device.getDeviceName()}",
            serial=info.getDeviceId(),
            width=w,
            height=h,
            fps=cfg.fps,
            state="streaming",
            extra={
                "platform": device.getPlatformAsString(),
                "preset": cfg.preset,
                "sockets": {"left": sockets.left.name, "right": sockets.right.name,
                            "image": sockets.color.name if sockets.color is not None else "rectified left"},
                "confidence": "delivered" if self._confidence_delivered(sockets) else
                              "not delivered (not registered to the colour image; use align=left)",
                "auto_calibration": cfg.auto_calibration,
            },
        )
        super().open()

    def _confidence_delivered(self, sockets: Sockets) -> bool:
        return self.config.confidence_map and sockets.color is None

    def _build(self, pipeline: dai.Pipeline, platform: dai.Platform, sockets: Sockets) -> dai.MessageQueue:
        cfg = self.config
        pipeline.setAutoCalibrationMode(AUTO_CALIBRATION[cfg.auto_calibration])
        left = pipeline.create(dai.node.Camera).build(sockets.left)
        right = pipeline.create(dai.node.Camera).build(sockets.right)
        mono = (cfg.mono_width, cfg.mono_height)
        stereo = pipeline.create(dai.node.StereoDepth).build(
            left.requestOutput(mono, fps=cfg.fps), right.requestOutput(mono, fps=cfg.fps), preset_mode(cfg.preset)
        )
        stereo.setDisparityToDepthUseSpecTranslation(False)
        # Only what the user set, on the config build() filled from the preset (the node's own
        # setLeftRightCheck & co. write the same initialConfig).
        configure_stereo(stereo.initialConfig, cfg)
        sync = pipeline.create(dai.node.Sync)
        sync.setSyncThreshold(timedelta(seconds=0.5 / cfg.fps))
        if sockets.color is None:
            # Depth, confidence and image all in the rectified left frame: registered by construction.
            stereo.setDepthAlign(dai.StereoDepthConfig.AlgorithmControl.DepthAlign.RECTIFIED_LEFT)
            stereo.rectifiedLeft.link(sync.inputs["rgb"])
            stereo.depth.link(sync.inputs["depth"])
            if cfg.confidence_map:
                stereo.confidenceMap.link(sync.inputs["conf"])
        else:
            color = pipeline.create(dai.node.Camera).build(sockets.color)
            # Undistorted colour so the pinhole intrinsics hold across the image.
            color_out = color.requestOutput(cfg.size, fps=cfg.fps, enableUndistortion=True)
            color_out.link(sync.inputs["rgb"])
            if platform == dai.Platform.RVC4:
                align = pipeline.create(dai.node.ImageAlign)
                stereo.depth.link(align.input)
                color_out.link(align.inputAlignTo)
                align.outputAligned.link(sync.inputs["depth"])
            else:
                color_out.link(stereo.inputAlignTo)
                stereo.depth.link(sync.inputs["depth"])
            # No confidence map here: it cannot be registered to colour on either platform (module docstring).
        # One message, older ones dropped: the newest frame wins, no queued latency in live view.
        return sync.out.createOutputQueue(maxSize=1, blocking=False)

    def read(self, timeout_s: float = 1.0) -> Frame:
        if not self.is_open or self._queue is None or self._camera is None:
            raise SourceError("the OAK source is not open; call open() or use `with open_source('oak') as src:`")
        group = read_group(self._queue, timeout_s, self._device)
        names = set(group.getMessageNames())
        rgb, depth = group["rgb"], group["depth"]
        conf = group["conf"] if "conf" in names else None
        if not isinstance(rgb, dai.ImgFrame) or not isinstance(depth, dai.ImgFrame):
            raise SourceError("the OAK pipeline sent a group without image frames")
        return frame_from_messages(
            rgb, depth, conf if isinstance(conf, dai.ImgFrame) else None, self._camera, self._baseline_m,
            {"serial": self.info.serial},
        )

    def _release(self) -> None:
        pipeline, device = self._pipeline, self._device
        self._pipeline = self._device = self._queue = None
        if pipeline is not None:
            try:
                pipeline.stop()
            except RuntimeError:
                pass  # already gone (cable pulled): nothing left to release
        if device is not None:
            try:
                device.close()
            except RuntimeError:
                pass

    def close(self) -> None:
        self._release()
        super().close()


def output_camera(calib: dai.CalibrationHandler, sockets: Sockets, cfg: OakConfig) -> PinholeCamera:
    """Fallback intrinsics of the output image (frames carrying an ImgTransformation override them).

    Colour: the colour camera's matrix at the output size. Rectified left: DepthAI rectifies both
    eyes onto the stereo *right* camera's matrix (its calibration reader builds the left
    rectification as ``M_right R1 M_left^-1``), so that matrix at the mono size.
    """
    if sockets.color is not None:
        return intrinsics_from_calibration(calib, cfg.width, cfg.height, sockets.color)
    return intrinsics_from_calibration(calib, cfg.mono_width, cfg.mono_height, sockets.right)


def config_from_spec(spec: SourceSpec) -> OakConfig:
    """OakConfig from ``oak[:<mxid>][?preset=HIGH_DETAIL&fps=10&size=1280x720&subpixel=1&lr_check=1
    &extended_disparity=0&confidence_threshold=55&confidence_map=1&align=auto&auto_calibration=off
    &search_timeout_ms=2000]``; options left out keep the preset's (or the default) value."""
    known = {f.name for f in fields(OakConfig)} - {"mxid", "width", "height"}
    kwargs: dict = {"mxid": spec.target}
    for key, value in spec.params.items():
        try:
            if key == "size":
                w, _, h = value.lower().partition("x")
                kwargs["width"], kwargs["height"] = int(w), int(h)
            elif key == "preset":
                kwargs["preset"] = value.upper()
            elif key in ("align", "auto_calibration"):
                kwargs[key] = value.lower()
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

