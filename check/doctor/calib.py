"""The calibration side of `depthruler doctor`: the calibration in use, as the frames carry it and as its file says.

A baseline outside :data:`BASELINE_M` is not a stereo camera's: most often ``T`` in another unit (mm,
cm, inches, or board squares when the calibration was run with a square size of 1, as OpenCV's
``stereo_calib`` sample does by default). Each likely unit is named with what to change.
"""

from __future__ import annotations

import math

from device.calibration.files import CalibrationRef
from device.errors import SourceError
from measure import Frame

from check.doctor.findings import Finding

BASELINE_M = (0.01, 0.5)  # plausible stereo baselines, metres: a phone's pair to a wide rig
UNITS = {"mm": 1e-3, "cm": 1e-2, "in": 0.0254}
FOV_DEG = (20.0, 150.0)  # plausible horizontal fields of view
RMS_WARN_PX, RMS_FAIL_PX = 0.5, 1.0  # stereo RMS reprojection error of the calibration


def calibration_ref(spec: str) -> CalibrationRef | None:
    """The calibration file a spec names (its ``calib=`` and ``calib_units=``), None for sources that carry
    their own (an OAK, a recording, the simulator) or a spec that does not parse (the open check says why)."""
    from device import source_config

    try:
        ref = getattr(source_config(spec), "calibration", None)
    except SourceError:
        return None
    return ref if isinstance(ref, CalibrationRef) and ref.path else None


def _origin(kind: str, ref: CalibrationRef | None) -> str:
    if ref is not None:
        unit = f"calib_units={ref.units}" if ref.units else "the file's units, else metres"
        return f"the file {ref.path} (T in {unit})"
    return {"oak": "the OAK's on-board calibration (DepthAI's cm, converted to m)",
            "replay": "the recording's manifest (as its source gave it)", "sim": "the simulator's rig",
            "bag": "the bag's camera_info and depth units"}.get(kind, f"the {kind} source")


def baseline_finding(frame: Frame, kind: str, ref: CalibrationRef | None) -> Finding:
    """"baseline": ``frame.baseline_m`` inside :data:`BASELINE_M`; outside, fail naming the likely unit of ``T``."""
    b = float(frame.baseline_m)
    lo, hi = BASELINE_M
    origin = _origin(kind, ref)
    measured = f"baseline {1000 * b:.2f} mm from {origin}"
    figures = {"baseline_m": b, "plausible_m": [lo, hi]}
    if lo <= b <= hi:
        return Finding("baseline", "pass", measured, "", figures)
    likely = [u for u, k in UNITS.items() if lo <= b * k <= hi]
    guesses = [f"{u} (it would be {1000 * b * UNITS[u]:.1f} mm)" for u in likely]
    if 1.0 <= b <= 60.0:
        guesses.append("board squares (a calibration run with square size 1: multiply T by the square side in m)")
    unit = f"T is probably in {' or '.join(guesses)}" if guesses else f"a stereo baseline lies in {lo * 100:g} - {hi * 100:g} cm"
    if ref is not None:
        to = "add calib_units=mm to the source spec" if "mm" in likely else "convert T in the file to metres"
        fix = f"{unit}; {to}, or recalibrate: depthruler calibrate"
    elif kind == "replay":
        fix = f"{unit}; the recording carries its source's baseline: fix that source's calibration and record again"
    elif kind == "oak":
        fix = f"{unit}; the on-board calibration is off: recalibrate the OAK with Luxonis' calibration tool"
    else:
        fix = f"{unit}; check the source's calibration"
    return Finding("baseline", "fail", f"{measured}: outside {lo * 100:g} cm - {hi * 100:g} cm", fix, figures)


def intrinsics_finding(frame: Frame) -> Finding:
    """"intrinsics": the field of view fx gives, square pixels, principal point inside the image."""
    cam = frame.camera
    fov = math.degrees(2 * math.atan(cam.width / (2 * cam.fx))) if cam.fx > 0 else math.nan
    aspect = cam.fx / cam.fy if cam.fy > 0 else math.nan
    measured = (f"fx {cam.fx:.1f} px, fy {cam.fy:.1f} px for {cam.width}x{cam.height}: horizontal field of view "
                f"{fov:.1f} deg, principal point ({cam.cx:.1f}, {cam.cy:.1f})")
    figures = {"fov_deg": fov, "fx_over_fy": aspect, "fx": cam.fx, "fy": cam.fy}
    if not (FOV_DEG[0] <= fov <= FOV_DEG[1]):
        return Finding("intrinsics", "fail", measured, "the intrinsics are for another image size: calibrate at the size "
                       "the camera streams, or scale fx, fy, cx, cy by the ratio of the widths", figures)
    if not (0 <= cam.cx < cam.width and 0 <= cam.cy < cam.height) or abs(aspect - 1) > 0.05:
        return Finding("intrinsics", "warn", measured, "fx and fy should nearly agree and the principal point lie in "
                       "the image: the calibration may be for another size or layout (side-by-side halves?)", figures)
    return Finding("intrinsics", "pass", measured, "", figures)


def rectification_finding(kind: str, ref: CalibrationRef | None) -> Finding:
    """"rectification": the stereo RMS reprojection error the calibration file states (px), where known."""
    if ref is None:
        return Finding("rectification", "skip", f"{_origin(kind, ref)} states no reprojection error; the board check "
                       "measures what the calibration gives")
    try:
        calib = ref.load()
    except SourceError as exc:
        return Finding("rectification", "fail", f"the calibration does not load: {exc}", "fix the calib= file")
    rms = float(calib.rms)
    figures = {"rms_px": None if math.isnan(rms) else rms, "image_size": list(calib.image_size),
               "baseline_m": calib.baseline_m}
    if math.isnan(rms):
        return Finding("rectification", "warn", f"{ref.path} states no RMS reprojection error (OpenCV sample files do not)",
                       "run `depthruler check` with a board in view to measure what it gives", figures)
    measured = f"stereo RMS reprojection error {rms:.3f} px ({ref.path})"
    if rms > RMS_FAIL_PX:
        return Finding("rectification", "fail", measured, "recalibrate: more board views across the whole image, a flat board, "
                       "no motion blur (depthruler calibrate)", figures)
    if rms > RMS_WARN_PX:
        return Finding("rectification", "warn", measured, "a calibration under 0.5 px gives steadier depth: recalibrate "
                       "with more, sharper views", figures)
    return Finding("rectification", "pass", measured, "", figures)
