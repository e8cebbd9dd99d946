"""Reading the OAK's on-device calibration: pinhole intrinsics at an output size (pixels) and the
calibrated stereo baseline (metres), as typed :class:`device.errors.CalibrationError` when absent."""

from __future__ import annotations

import depthai as dai
import numpy as np

from measure import PinholeCamera

from device.errors import CalibrationError
from device.sources.oak.config import COLOR_SOCKET, OakConfig
from device.sources.oak.pipeline import Sockets

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


def output_camera(calib: dai.CalibrationHandler, sockets: Sockets, cfg: OakConfig) -> PinholeCamera:
    """Fallback intrinsics of the output image (frames carrying an ImgTransformation override them).

    Colour: the colour camera's matrix at the output size. Rectified left: DepthAI rectifies both
    eyes onto the stereo *right* camera's matrix (its calibration reader builds the left
    rectification as ``M_right R1 M_left^-1``), so that matrix at the mono size.
    """
    if sockets.color is not None:
        return intrinsics_from_calibration(calib, cfg.width, cfg.height, sockets.color)
    return intrinsics_from_calibration(calib, cfg.mono_width, cfg.mono_height, sockets.right)
