"""Which cameras are attached: DepthAI devices, V4L2 nodes and USB ids (docs/design.md "Sources").

Three independent probes, each failing soft: a machine without libusb, without ``/dev/video*``
or without DepthAI gets an empty list from that probe, never an exception, so ``depthruler
devices`` always answers.
"""

from __future__ import annotations

import os
from pathlib import Path

from device.base import SourceInfo

MOVIDIUS_VENDOR = 0x03E7  # Intel Movidius: every OAK (RVC2) enumerates with this vendor id
USB_CLASS_VIDEO = 14  # bInterfaceClass of UVC cameras
# Movidius product ids: what state the OAK is in (it re-enumerates after boot).
OAK_UDEV_RULE = 'SUBSYSTEM=="usb", ATTRS{idVendor}=="03e7", MODE="0666"'
UDEV_FIX = (f"echo '{OAK_UDEV_RULE}' | sudo tee /etc/udev/rules.d/80-movidius.rules && "
            "sudo udevadm control --reload-rules && sudo udevadm trigger  # then replug the OAK")
OAK_PRODUCTS = {0x2485: "unbooted", 0xF63B: "booted", 0xF63C: "bootloader", 0xF63D: "flash-booted"}


def list_devices() -> list[SourceInfo]:
    """All attached cameras from every probe, DepthAI first (it knows device state and mxid)."""
    return list_depthai() + list_v4l2() + list_usb()


def list_depthai() -> list[SourceInfo]:
    """OAK devices as DepthAI sees them, with their XLink state (unbooted, bootloader, booted...).

    ``getAllConnectedDevices`` also lists devices already opened by another program (state
    "booted"), which ``getAllAvailableDevices`` hides; telling the user it is busy beats silence.
    Invalid devices are listed too (``skipInvalidDevices=False``): one this user may not open
    (``X_LINK_INSUFFICIENT_PERMISSIONS``) gets state "no-permission" and the udev rule in ``extra``.
    """
    os.environ.setdefault("DEPTHAI_LEVEL", "error")
    try:
        import depthai as dai

        infos = dai.XLinkConnection.getAllConnectedDevices(skipInvalidDevices=False)
    except Exception:  # no SDK, or XLink cannot initialise (no USB access in a container)
        return []
    out = []
    for info in infos:
        denied = getattr(info, "status", None) == dai.XLinkError_t.X_LINK_INSUFFICIENT_PERMISSIONS
        state = str(getattr(info, "state", "")).rsplit(".", 1)[-1].replace("X_LINK_", "").lower()
        if denied:
            state = "no-permission"
        protocol = str(getattr(info, "protocol", "")).rsplit(".", 1)[-1].replace("X_LINK_", "").lower()
        platform = str(getattr(info, "platform", "")).rsplit(".", 1)[-1].replace("X_LINK_", "").lower()
        mxid = info.getDeviceId() if hasattr(info, "getDeviceId") else getattr(info, "deviceId", "")
        out.append(
            SourceInfo(
                kind="oak",
                name=f"OAK {info.name}".strip(),
                serial=mxid,
                state=state,
                extra={"protocol": protocol, "platform": platform, "spec": f"oak:{mxid}" if mxid else "oak",
                       **({"fix": UDEV_FIX} if denied else {})},
            )
        )
    return out


V4L2_CAP_VIDEO_CAPTURE = 0x00000001
V4L2_CAP_VIDEO_CAPTURE_MPLANE = 0x00001000
V4L2_CAP_DEVICE_CAPS = 0x80000000
VIDIOC_QUERYCAP = 0x80685600  # _IOR('V', 0, struct v4l2_capability), 104 bytes


def querycap(node: Path) -> int | str:
    """The node's V4L2 device capabilities (``VIDIOC_QUERYCAP``), or why they cannot be read:
    "no-permission" (EACCES: fixed by the video group) or "unknown" (busy, not a V4L2 node...)."""
    import fcntl
    import struct

    try:
        fd = os.open(node, os.O_RDWR | os.O_NONBLOCK)
    except PermissionError:
        return "no-permission"
    except OSError:
        return "unknown"
    try:
        buf = fcntl.ioctl(fd, VIDIOC_QUERYCAP, bytes(104))
    except OSError:
        return "unknown"
    finally:
        os.close(fd)
    caps, device_caps = struct.unpack_from("=II", buf, 84)  # after driver[16], card[32], bus_info[32], version
    return device_caps if caps & V4L2_CAP_DEVICE_CAPS else caps


def list_v4l2(sys_root: Path = Path("/sys/class/video4linux"), dev_root: Path = Path("/dev"),
              query=querycap) -> list[SourceInfo]:
    """V4L2 nodes ``/dev/video*`` that capture video, with the driver's name for each (from sysfs).

    A UVC camera exposes a second node for metadata (``V4L2_CAP_META_CAPTURE``) that delivers no
    images: nodes whose capabilities lack video capture are left out. When the capabilities cannot
    be read, sysfs ``index`` decides (a camera's first node has index 0, its metadata node 1), and
    a node this user may not open is listed with state "no-permission" and the fix.
    """
    try:
        nodes = sorted(dev_root.glob("video[0-9]*"), key=lambda p: int(p.name[5:]))
    except OSError:
        return []
    out = []
    for node in nodes:
        name = _sysfs(sys_root / node.name / "name")
        caps = query(node)
        if isinstance(caps, int):
            if not caps & (V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_VIDEO_CAPTURE_MPLANE):
                continue  # metadata / output / codec node: nothing to capture from
        elif _sysfs(sys_root / node.name / "index") not in ("", "0"):
            continue
        extra: dict = {"spec": f"v4l2:{node}"}
        if caps == "no-permission":
            extra["fix"] = ("sudo usermod -aG video $USER  # then log out and in (permission denied on "
                            f"{node}: this is not 'busy')")
        out.append(SourceInfo(kind="v4l2", name=name or node.name, serial=str(node),
                              state="no-permission" if caps == "no-permission" else "", extra=extra))
    return out


def _sysfs(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""  # node without a sysfs entry (e.g. a container bind mount): still listable


def list_usb() -> list[SourceInfo]:
    """USB devices that are cameras: OAKs (vendor 03e7) and UVC cameras (interface class 14).

    Uses pyusb with the libusb shipped in the ``libusb-package`` wheel, so no system libusb is needed.
    """
    try:
        import libusb_package
        import usb.core

        backend = libusb_package.get_libusb1_backend()
        if backend is None:
            return []
        devices = list(usb.core.find(find_all=True, backend=backend))
    except Exception:  # no libusb, no permission on /dev/bus/usb, no USB at all
        return []
    out = []
    for dev in devices:
        try:
            info = usb_camera_info(dev)
        except Exception:  # one odd device must not hide the others
            continue
        if info is not None:
            out.append(info)
    return out


def usb_camera_info(dev) -> SourceInfo | None:
    """A SourceInfo for a pyusb device if it is an OAK or a UVC camera, else None."""
    vid, pid = int(dev.idVendor), int(dev.idProduct)
    usb_id = f"{vid:04x}:{pid:04x}"
    where = f"bus {getattr(dev, 'bus', '?')} address {getattr(dev, 'address', '?')}"
    if vid == MOVIDIUS_VENDOR:
        return SourceInfo(
            kind="usb",
            name="Luxonis OAK (Movidius)",
            serial=_usb_string(dev, "serial_number"),
            state=OAK_PRODUCTS.get(pid, "unknown"),
            extra={"usb_id": usb_id, "where": where, "spec": "oak"},
        )
    if not _is_uvc(dev):
        return None
    name = " ".join(s for s in (_usb_string(dev, "manufacturer"), _usb_string(dev, "product")) if s)
    return SourceInfo(
        kind="usb",
        name=name or f"UVC camera {usb_id}",
        serial=_usb_string(dev, "serial_number"),
        extra={"usb_id": usb_id, "where": where, "uvc": True},
    )


def _is_uvc(dev) -> bool:
    if int(getattr(dev, "bDeviceClass", 0)) == USB_CLASS_VIDEO:
        return True
    for cfg in dev:
        for intf in cfg:
            if int(intf.bInterfaceClass) == USB_CLASS_VIDEO:
                return True
    return False


def _usb_string(dev, attr: str) -> str:
    # Reading string descriptors needs write access to the device node; without it, stay nameless.
    try:
        return (getattr(dev, attr) or "").strip()
    except Exception:
        return ""
