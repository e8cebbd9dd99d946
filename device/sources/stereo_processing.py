"""Stereo pair processing: rectification from the calibration, SGBM, and the Frame registered to the
*rectified left* colour image, for every stereo source without on-board depth (live pairs, video files,
memory).

A :class:`FrameGrabber` yields (left, right, timestamp in s) — ``device.sources.stereo_pair`` from
cameras or memory, ``device.sources.video`` from files — and :class:`StereoProcessor` turns a pair into a
:class:`measure.Frame`: rectification from the calibration (device/calibration/, ``cv2.stereoRectify``),
SGBM (device/sources/sgbm.py), ``Z = fx * B / (d + doffs)`` in metres with disparity in pixels.
:class:`ProcessedPairSource` is grabber + calibration + processor.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np

from measure import Frame, MeasureError, PinholeCamera

from device.base import SourceBase, SourceInfo, SourceSpec, parse_flag
from device.calibration.files import CalibrationRef
from device.calibration.stereo import StereoCalibration
from device.errors import CalibrationError, SourceError
from device.sources.sgbm import MODES, SGBMConfig, compute_disparity


class FrameGrabber(Protocol):
    """Where stereo pairs come from: cameras, files or memory. ``grab`` returns BGR left, right, seconds."""

    def open(self) -> None: ...

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]: ...

    def close(self) -> None: ...


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
