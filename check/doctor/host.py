"""The host side of `depthruler doctor`: package versions, and the cameras on the USB bus (speed, permissions).

USB facts come from sysfs (``/sys/bus/usb/devices/*``: ``idVendor``, ``speed`` in Mbit/s, ``busnum``,
``devnum``, interface classes), which is what the kernel negotiated, whatever the SDK says; the
device node ``/dev/bus/usb/BBB/DDD`` must be readable and writable for DepthAI or libusb to open it.
"""

from __future__ import annotations

import importlib.metadata as metadata
import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from device.discovery import MOVIDIUS_VENDOR, OAK_PRODUCTS, UDEV_FIX, list_v4l2

from check.doctor.findings import Finding, worst

SYS_USB = Path("/sys/bus/usb/devices")
DEV_USB = Path("/dev/bus/usb")
USB_KINDS = ("oak", "v4l2")  # the source kinds that read a USB camera
USB3_MBPS = 5000  # sysfs "speed" of a SuperSpeed link; a USB2 (high-speed) link says 480
OPENCV_WHEELS = ("opencv-python", "opencv-python-headless", "opencv-contrib-python", "opencv-contrib-python-headless")
UVC_PERMISSION_FIX = "sudo usermod -aG video $USER  # then log out and in"


@dataclass(frozen=True)
class UsbCamera:
    """A camera on the USB bus as sysfs shows it: ``speed_mbps`` negotiated (480 = USB2, 5000 = USB3)."""

    name: str  # sysfs device name, e.g. "2-1"
    usb_id: str  # "03e7:f63b"
    product: str
    speed_mbps: float
    node: Path  # /dev/bus/usb/BBB/DDD
    oak: bool

    @property
    def state(self) -> str:
        return OAK_PRODUCTS.get(int(self.usb_id[5:], 16), "unknown") if self.oak else "uvc"


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def usb_cameras(sys_root: Path = SYS_USB, dev_root: Path = DEV_USB) -> list[UsbCamera]:
    """OAKs (vendor 03e7) and UVC cameras (an interface of class 0e) in sysfs ``sys_root``."""
    out = []
    try:
        entries = sorted(p for p in sys_root.iterdir() if ":" not in p.name)
    except OSError:
        return []
    for dev in entries:
        vid, pid = _read(dev / "idVendor"), _read(dev / "idProduct")
        if not vid or not pid:
            continue  # a hub's port or an interface
        oak = int(vid, 16) == MOVIDIUS_VENDOR
        uvc = any(_read(i / "bInterfaceClass") == "0e" for i in dev.glob(f"{dev.name}:*"))
        if not (oak or uvc):
            continue
        try:
            speed = float(_read(dev / "speed") or "nan")
            node = dev_root / f"{int(_read(dev / 'busnum')):03d}" / f"{int(_read(dev / 'devnum')):03d}"
        except ValueError:
            continue
        product = " ".join(x for x in (_read(dev / "manufacturer"), _read(dev / "product")) if x)
        out.append(UsbCamera(dev.name, f"{vid}:{pid}", product or ("Luxonis OAK" if oak else "UVC camera"), speed, node, oak))
    return out


def usb_findings(kind: str, sys_root: Path = SYS_USB, dev_root: Path = DEV_USB,
                 video_root: Path = Path("/dev"), video_sys: Path = Path("/sys/class/video4linux")) -> list[Finding]:
    """The "usb-speed" and "usb-permission" findings for a source of ``kind`` (skipped for files and the simulator)."""
    if kind not in USB_KINDS:
        why = f"a {kind} source reads no USB camera"
        return [Finding("usb-speed", "skip", why), Finding("usb-permission", "skip", why)]
    if not sys_root.is_dir():
        msg = f"{sys_root} is not visible, so the USB link cannot be read"
        fix = "outside a container this is always there; in one, add -v /sys:/sys:ro -v /dev/bus/usb:/dev/bus/usb"
        return [Finding("usb-speed", "warn", msg, fix), Finding("usb-permission", "warn", msg, fix)]
    cams = [c for c in usb_cameras(sys_root, dev_root) if c.oak == (kind == "oak")]
    what = "OAK (USB vendor 03e7)" if kind == "oak" else "UVC camera"
    if not cams:
        plug = ("plug the OAK into a USB3 port (blue, or marked SS) with its USB3 cable" if kind == "oak"
                else "plug the stereo camera in, then `depthruler devices` lists its /dev/video node")
        msg = f"no {what} on the USB bus"
        return [Finding("usb-speed", "fail", msg, plug), Finding("usb-permission", "fail", msg, plug)]
    return [_speed(cams), _permission(cams, kind, video_root, video_sys)]


def _speed(cams: Sequence[UsbCamera]) -> Finding:
    parts, fixes, states = [], [], []
    for c in cams:
        link = "USB3" if c.speed_mbps >= USB3_MBPS else "USB2" if c.speed_mbps >= 480 else "USB1"
        parts.append(f"{c.product} {c.usb_id} at {c.speed_mbps:g} Mbit/s ({link}){f', {c.state}' if c.oak else ''}")
        if c.speed_mbps >= USB3_MBPS or (not c.oak and c.speed_mbps >= 480):
            states.append("pass")
        elif c.oak and c.speed_mbps >= 480:
            states.append("warn")
            fixes.append(f"{c.name}: the OAK runs on a USB2 link (fewer fps, or DepthAI falls back to lower sizes): "
                         "plug it straight into a USB3 port with a USB3 cable (no USB2 hub or extension)")
        else:
            states.append("fail")
            fixes.append(f"{c.name}: a {c.speed_mbps:g} Mbit/s link cannot carry video: use another port or cable")
    figures = {"speed_mbps": [c.speed_mbps for c in cams], "usb_id": [c.usb_id for c in cams]}
    return Finding("usb-speed", worst([Finding("x", s, "") for s in states]), "; ".join(parts), "; ".join(fixes), figures)


def _permission(cams: Sequence[UsbCamera], kind: str, video_root: Path, video_sys: Path) -> Finding:
    denied = [c for c in cams if not os.access(c.node, os.R_OK | os.W_OK)]
    nodes = [] if kind == "oak" else [v for v in list_v4l2(video_sys, video_root) if v.state == "no-permission"]
    if not denied and not nodes:
        return Finding("usb-permission", "pass", "this user may open " + ", ".join(str(c.node) for c in cams))
    msg = "no read/write permission on " + ", ".join([str(c.node) for c in denied] + [v.serial for v in nodes])
    return Finding("usb-permission", "fail", msg, UDEV_FIX if kind == "oak" else UVC_PERMISSION_FIX)


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def version_findings(kind: str) -> list[Finding]:
    """The "versions" finding: Python, NumPy, OpenCV (with ArUco's ChArUco detector), DepthAI and rosbags,
    each against the minimum the project's own metadata requires (when the project is installed)."""
    from packaging.requirements import Requirement

    import cv2
    import numpy

    required = {}
    for text in (metadata.requires("depthruler") if _version("depthruler") else None) or []:
        req = Requirement(text)
        if req.marker is None:
            required[req.name] = req.specifier
    found = {"python": platform.python_version(), "numpy": numpy.__version__, "opencv": cv2.__version__,
             "depthai": _version("depthai"), "rosbags": _version("rosbags")}
    problems: list[tuple[str, str]] = []  # (status, fix)
    for dist in ("numpy", "opencv-contrib-python-headless", "depthai", "rosbags"):
        have = _version(dist)
        if have is not None and dist in required and have not in required[dist]:
            problems.append(("fail", f"{dist} {have} is older than the {required[dist]} depthruler needs: "
                                     f"pip install -U '{dist}{required[dist]}'"))
    wheels = [w for w in OPENCV_WHEELS if _version(w)]
    if len(wheels) > 1:
        problems.append(("warn", f"{len(wheels)} OpenCV wheels ({', '.join(wheels)}) share the one cv2 module and overwrite "
                                 f"each other: pip uninstall {' '.join(wheels)}, then pip install opencv-contrib-python-headless"))
    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "CharucoDetector"):
        problems.append(("fail", f"OpenCV {cv2.__version__} has no cv2.aruco.CharucoDetector (board check and calibration): "
                                 "pip install 'opencv-contrib-python-headless>=4.10'"))
    for dist, needed in (("depthai", "oak"), ("rosbags", "bag")):
        if found[dist] is None and kind == needed:
            problems.append(("fail", f"a {needed} source needs {dist}: pip install {dist}"))
    measured = ", ".join(f"{k} {v or 'not installed'}" for k, v in found.items())
    status = worst([Finding("x", s, "") for s, _ in problems])
    return [Finding("versions", status, measured, "; ".join(f for _, f in problems), found)]


DEPTHAI_SPEEDS = {"LOW": 1.5, "FULL": 12.0, "HIGH": 480.0, "SUPER": 5000.0, "SUPER_PLUS": 10000.0}  # dai.UsbSpeed, Mbit/s


def with_depthai_speed(found: Finding, said: str) -> Finding:
    """``found`` ("usb-speed" from sysfs) with what DepthAI reports for the open device (``dai.UsbSpeed`` name, as an
    OAK source states it in ``info.extra["usb_speed"]``); DepthAI's word decides when sysfs could not be read."""
    name = str(said).rsplit(".", 1)[-1].upper()
    mbps = DEPTHAI_SPEEDS.get(name)
    if mbps is None:
        return found
    status = "pass" if mbps >= USB3_MBPS else "warn" if mbps >= 480 else "fail"
    fix = "" if status == "pass" else ("DepthAI runs the OAK over a USB2 link: plug it straight into a USB3 port with a USB3 "
                                       "cable (no USB2 hub or extension)")
    measured = f"{found.measured}; DepthAI says {name} ({mbps:g} Mbit/s)"
    # without a sysfs reading (no /sys in a container) the open device's own word decides; with one, the worse
    merged = status if "speed_mbps" not in found.figures else worst([found, Finding("x", status, "")])
    return Finding("usb-speed", merged, measured, "; ".join(x for x in (found.fix, fix) if x),
                   {**found.figures, "depthai_usb_speed": name})
