"""The ``oak`` source: finding the device (with the udev rule when this user may not open it), opening
it with its calibration and pipeline, and reading frames."""

from __future__ import annotations

import time

import depthai as dai

from measure import Frame, PinholeCamera

from device.base import SourceBase, SourceInfo
from device.discovery import OAK_UDEV_RULE, list_usb
from device.errors import SourceError, SourceNotFound
from device.sources.oak.calibration import baseline_m_from_calibration, output_camera
from device.sources.oak.config import OakConfig
from device.sources.oak.frames import frame_from_messages, read_group
from device.sources.oak.pipeline import Sockets, build_pipeline, choose_sockets

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
            wired = build_pipeline(pipeline, device.getPlatform(), sockets, cfg)
            self._queue = wired.queue
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
                "depth": wired.depth,
                # the link after boot: an OAK on a USB2 port or cable streams, but at a fraction of the rate
                "usb_speed": str(device.getUsbSpeed().name),
            },
        )
        super().open()

    def _confidence_delivered(self, sockets: Sockets) -> bool:
        return self.config.confidence_map and sockets.color is None

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
            {"serial": self.info.serial, "depth_postprocessing": "measurement"},
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
