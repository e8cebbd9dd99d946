"""Lens distortion from camera_info, and resampling a distorted image onto the pinhole camera of its K.

librealsense and depthai-ros publish distorted colour images with the distortion in ``camera_info``
(``D`` with ``distortion_model``). Frames are pinhole (``measure.PinholeCamera``), so a bag's colour
image and its registered depth are both resampled onto the undistorted image of the same K and size:
colour bilinearly, depth by nearest neighbour (no depth invented between surfaces). Models:
``plumb_bob`` / ``rational_polynomial`` (ROS names; OpenCV's coefficient order k1 k2 p1 p2 [k3 [k4 k5
k6 [s1..s4 [tx ty]]]]), the Viewer's ``Brown Conrady`` (the same forward model), ``Modified Brown
Conrady`` (tangential terms on the radially distorted point) and ``Inverse Brown Conrady``
(librealsense's colour model: the polynomial maps distorted to undistorted coordinates).
All-zero coefficients are no distortion whatever the model. Why and what it changes:
docs/decisions/bag-source.md ("Distortion").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from measure import PinholeCamera

from device.sources.bag.errors import BagError

FORWARD_MODELS = ("plumb_bob", "rational_polynomial", "brown_conrady")
INVERSE_MODELS = ("inverse_brown_conrady",)
LIBREALSENSE_MODELS = ("modified_brown_conrady", *INVERSE_MODELS)  # five coefficients k1 k2 p1 p2 k3
OPENCV_LENGTHS = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class Distortion:
    """A camera_info's lens distortion: ``model`` (normalised: lower case, ``_`` for spaces) and ``coeffs``."""

    model: str = "none"
    coeffs: tuple[float, ...] = ()

    @property
    def is_none(self) -> bool:
        return not any(self.coeffs)


def distortion_from_info(msg: Any, topic: str) -> Distortion:
    """The :class:`Distortion` of a sensor_msgs/CameraInfo (ROS 1 ``D``, ROS 2 ``d``); a typed
    :class:`BagError` for a model with non-zero coefficients that this reader cannot undo."""
    d = np.asarray(getattr(msg, "d", getattr(msg, "D", ())), dtype=np.float64).ravel()
    model = str(getattr(msg, "distortion_model", "") or "none").strip().lower().replace(" ", "_").replace("-", "_")
    if not np.all(np.isfinite(d)):
        raise BagError(f"{topic}: camera_info distortion D={d.tolist()} is not finite; the bag's calibration is damaged")
    dist = Distortion(model=model, coeffs=tuple(float(x) for x in d))
    if dist.is_none:
        return Distortion(model=model, coeffs=())
    if model in FORWARD_MODELS and d.size in OPENCV_LENGTHS:
        return dist
    if model in LIBREALSENSE_MODELS and d.size == 5:
        return dist
    raise BagError(
        f"{topic}: camera_info distortion model {msg.distortion_model!r} with {d.size} non-zero coefficients is not "
        "supported (plumb_bob, rational_polynomial, Brown Conrady with 4/5/8/12/14; Modified or Inverse Brown "
        "Conrady with 5); "
        "record the rectified image topic (image_rect) with its camera_info instead"
    )


def _grid(cam: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """Normalised coordinates of every pixel centre of ``cam`` (x right, y down)."""
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    return (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy


def _modified_brown_conrady(cam: PinholeCamera, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Maps for librealsense's projection model: radial scaling first, then the tangential terms."""
    k1, k2, p1, p2, k3 = coeffs
    x, y = _grid(cam)
    r2 = x * x + y * y
    f = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    x, y = x * f, y * f
    xd = x + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    return (xd * cam.fx + cam.cx).astype(np.float32), (yd * cam.fy + cam.cy).astype(np.float32)


def _inverse_brown_conrady(cam: PinholeCamera, coeffs: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Maps for librealsense's inverse model: ``undistorted = f(distorted)``, so each undistorted pixel's
    source is found by fixed-point iteration ``d <- d + (u - f(d))`` (converges for lens-sized terms)."""
    k1, k2, p1, p2, k3 = coeffs
    xu, yu = _grid(cam)
    x, y = xu.copy(), yu.copy()
    for _ in range(20):
        r2 = x * x + y * y
        f = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        fx_ = x * f + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        fy_ = y * f + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
        x, y = x + (xu - fx_), y + (yu - fy_)
    return (x * cam.fx + cam.cx).astype(np.float32), (y * cam.fy + cam.cy).astype(np.float32)


def undistort_maps(cam: PinholeCamera, dist: Distortion) -> tuple[np.ndarray, np.ndarray] | None:
    """For each pixel of the pinhole image of ``cam`` (same K and size), where to sample the distorted
    image (two H x W float32 maps, pixels); None when there is no distortion."""
    if dist.is_none:
        return None
    import cv2  # lazily, as the rest of the bag package: `import device` stays fast

    if dist.model in INVERSE_MODELS:
        return _inverse_brown_conrady(cam, dist.coeffs)
    if dist.model == "modified_brown_conrady":
        return _modified_brown_conrady(cam, dist.coeffs)
    K = np.array([[cam.fx, 0.0, cam.cx], [0.0, cam.fy, cam.cy], [0.0, 0.0, 1.0]])
    return cv2.initUndistortRectifyMap(K, np.array(dist.coeffs), None, K, (cam.width, cam.height), cv2.CV_32FC1)


def remap(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray] | None, *, nearest: bool) -> np.ndarray:
    """``image`` resampled through :func:`undistort_maps`: bilinear for colour (black outside), nearest for
    depth in metres (NaN outside); ``image`` itself when ``maps`` is None."""
    if maps is None:
        return image
    import cv2

    if nearest:
        return cv2.remap(np.asarray(image, dtype=np.float32), maps[0], maps[1], cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
    return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
