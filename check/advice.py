"""What to do about a depth scale or a disparity offset, for the kind of camera the frames came from.

A stereo pair processed here (``v4l2``, ``video``, and the simulator, which stands for one) computes
depth from the calibration file's T and principal points, so a scale error is fixed by recalibrating
or scaling T, and an offset is in the file. A device that delivers depth (``oak``, a RealSense or
DepthAI ``bag``) converts it with ``d = fx B / Z``: the baseline cancels out of every length, and only
the device's own calibration sets the scale, so the fix is the vendor's calibration tool. A folder of
depth images or a dataset has no camera to recalibrate: its depth unit or its calib file is the
suspect. :func:`advice_for` gives each kind its words; the kind is the frames' ``meta["source"]``
(a replayed recording keeps the kind of the camera it recorded).
"""

from __future__ import annotations

from dataclasses import dataclass

STEREO_KINDS = ("v4l2", "video", "sim")
DEVICE_KINDS = ("oak", "bag")
FILE_KINDS = ("depthpng", "middlebury")


@dataclass(frozen=True)
class Advice:
    """The words for one kind of camera: where a scale error comes from and what fixes it, the same for
    a depth error that grows with distance (``{pct}``: the bias in %; ``{factor}``: the factor on T)."""

    family: str  # "stereo" | "device" | "file" | "unknown"
    scale_cause: str
    scale_action: str
    offset_cause: str  # why the bias grows with distance ({delta}: the disparity offset in px that would do it)
    offset_action: str


_STEREO = Advice(
    "stereo",
    scale_cause="the baseline in the calibration is probably off by about {pct:+.1f} %",
    scale_action="recalibrate (depthruler calibrate) or scale the calibration's T by {factor:.4f}",
    offset_cause="a disparity offset of about {delta:+.2f} px (the calibration's principal points or doffs, or the "
                 "rectification), not only the baseline, which would read the same % at every distance",
    offset_action="recalibrate with board views spread over the working distances",
)
_DEVICE = {
    "oak": "recalibrate the OAK with Luxonis' calibration (depthai calibrate.py, written to the device's EEPROM), "
           "or restore its factory calibration",
    "bag": "recalibrate the camera with its vendor's tool (RealSense: on-chip calibration and tare in the "
           "RealSense Viewer; OAK: Luxonis' calibration) and record the bag again",
}
_FILE = {
    "depthpng": "check the folder's depth unit (depth_scale: metres per depth count) and the intrinsics it was given",
    "middlebury": "check the scene's calib.txt (baseline, doffs, focal length) against the images",
}


def advice_for(kind: str | None) -> Advice:
    """The advice for frames whose ``meta["source"]`` is ``kind`` (None or unknown: words that hold for any camera)."""
    if kind in STEREO_KINDS:
        return _STEREO
    if kind in DEVICE_KINDS:
        fix = _DEVICE[kind]
        return Advice(
            "device",
            scale_cause="the camera's depth scale is probably off by about {pct:+.1f} % (its own calibration: the "
                        "baseline cancels out of lengths from delivered depth)",
            scale_action=fix,
            offset_cause="a depth error that grows with distance: the device's calibration or its depth processing "
                         "(the stereo matcher's sub-pixel bias), not the baseline, which would read the same % everywhere",
            offset_action=fix,
        )
    if kind in FILE_KINDS:
        fix = _FILE[kind]
        return Advice(
            "file",
            scale_cause="the depth's scale is probably off by about {pct:+.1f} % (the depth unit or the calibration "
                        "the files came with)",
            scale_action=fix,
            offset_cause="a depth error that grows with distance: the calibration the files came with (e.g. doffs) "
                         "or an offset in the depth values, not a scale, which would read the same % everywhere",
            offset_action=fix,
        )
    return Advice(
        "unknown",
        scale_cause="the camera's depth scale (its calibration's baseline) is probably off by about {pct:+.1f} %",
        scale_action="recalibrate the camera (depthruler calibrate for a stereo pair, the vendor's tool for a "
                     "depth camera)",
        offset_cause="a depth error that grows with distance (the camera's calibration), not a scale, which would "
                     "read the same % at every distance",
        offset_action="recalibrate the camera with board views spread over the working distances",
    )
