"""`depthruler doctor` as one function: every check on one source, in the order a person would fix them.

Host first (versions, then USB speed and permissions, read once the source is open: an OAK boots over
USB2 and re-enumerates at its link's speed), then the stream (does it open, frames and their rate,
timestamps, registration, fill), then the calibration the frames carry (baseline, intrinsics,
rectification error), then the board check when a board is in view. A check that cannot run
because an earlier one failed (no frame) is listed with status "skip", so every check is reported.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from device import SourceError, SourceSpec, list_devices, make_source
from device.errors import CalibrationError, SourceNotFound
from device.calibration.board import BoardSpec

from check.doctor import board as board_checks
from check.doctor import calib, host, stream
from check.doctor.findings import DoctorReport, Finding

WINDOW_S = 10.0
CAMERA_KINDS = ("oak", "v4l2", "usb")  # sources that are a device on this machine
AFTER_OPEN = ("frames", "timestamps", "registration", "fill", "baseline", "intrinsics", "rectification", "board")
NO_CAMERA = ("no camera found (no OAK over DepthAI, no /dev/video node, no USB video device): plug in an OAK-D "
             "into a USB3 port, or a UVC stereo camera (then --source v4l2:/dev/videoN?calib=FILE); "
             "or try `depthruler doctor --source sim`")


def attached_source() -> str | None:
    """The spec of the camera to check when none is named: the first OAK, else the first V4L2 node; None without one."""
    found = list_devices()
    for kind in ("oak", "v4l2", "usb"):
        for d in found:
            if d.kind == kind and d.extra.get("spec"):
                return str(d.extra["spec"])
    return None


def run_doctor(spec: str, *, window_s: float = WINDOW_S, board: BoardSpec | None = None,
               progress: Callable[[str], None] = lambda _: None, sys_root: Path = host.SYS_USB,
               dev_root: Path = host.DEV_USB) -> DoctorReport:
    """Every check on source ``spec``; the source is read for ``window_s`` seconds (host clock). ``board``:
    the printed board to look for (default: the source's own, else :class:`BoardSpec`'s default)."""
    try:
        kind = SourceSpec.parse(spec).kind
    except SourceError as exc:
        return DoctorReport(spec, (Finding("open", "fail", str(exc), "fix the --source spec"),))
    found = host.version_findings(kind)
    progress(f"opening {spec}")
    t0 = time.monotonic()
    try:
        src = make_source(spec)
        src.open()
    except SourceError as exc:  # the message says what to plug in, install or fix
        found += host.usb_findings(kind, sys_root, dev_root)
        found.append(Finding("open", "fail", f"{spec} does not open: {exc}", _open_fix(kind, exc)))
        found += [Finding(name, "skip", "the source did not open") for name in AFTER_OPEN]
        return DoctorReport(spec, tuple(found), note=_no_camera(kind, exc))
    try:
        opened_s = time.monotonic() - t0
        info = src.info
        # read while the source is open: an OAK boots over USB2 and re-enumerates at its real speed
        usb = host.usb_findings(kind, sys_root, dev_root)
        said = info.extra.get("usb_speed") if isinstance(info.extra, dict) else None
        if said:  # an OAK source that states DepthAI's dai.UsbSpeed of the open device
            usb = [host.with_depthai_speed(f, said) if f.check == "usb-speed" else f for f in usb]
        found += usb
        found.append(Finding("open", "pass", f"{info.name} ({info.kind}, serial {info.serial or '-'}) opened in {opened_s:.1f} s",
                             "", {"open_s": opened_s, "kind": info.kind, "serial": info.serial}))
        progress(f"reading for {window_s:g} s")
        window = stream.read_window(src, window_s)
    finally:
        src.close()
    found += [stream.frames_finding(window), stream.timestamps_finding(window), stream.shape_finding(window),
              stream.fill_finding(window)]
    ref = calib.calibration_ref(spec)
    if window.first is None:
        found += [Finding(name, "skip", "no frame arrived") for name in ("baseline", "intrinsics")]
    else:
        found += [calib.baseline_finding(window.first, kind, ref), calib.intrinsics_finding(window.first)]
    found.append(calib.rectification_finding(kind, ref))
    progress("looking for a board")
    chosen = board or board_checks.source_board(spec) or BoardSpec()
    found.append(board_checks.board_finding(window.last, chosen))
    return DoctorReport(spec, tuple(found))


def _no_camera(kind: str, exc: SourceError) -> str:
    """:data:`NO_CAMERA` when a camera source is not found and the machine lists no camera at all, else ""
    (with another camera attached, the open finding names the one that is missing)."""
    if not isinstance(exc, SourceNotFound) or kind not in CAMERA_KINDS:
        return ""
    return "" if list_devices() else NO_CAMERA


def _open_fix(kind: str, exc: SourceError) -> str:
    if isinstance(exc, CalibrationError):  # the device is there; its calibration is refused, and the message says why
        return "the calibration is refused, not the device: change what the message names, then run the doctor again"
    return {"oak": "plug the OAK into a USB3 port; if `depthruler devices` shows no-permission, add the udev rule it prints",
            "v4l2": "name the node and its calibration: v4l2:/dev/videoN?layout=side-by-side&calib=FILE",
            "video": "name the file and its calibration: video:pair.mkv?layout=side-by-side&calib=FILE",
            "replay": "name a folder written by `depthruler record` (it holds manifest.json)"}.get(kind, "fix what the message names")
