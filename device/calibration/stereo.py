"""A calibrated stereo pair (:class:`StereoCalibration`) and the project's native JSON calibration file.

The project's native calibration file (JSON, ``FORMAT`` / ``VERSION``), read by :func:`load_calibration`
(OpenCV FileStorage and ROS camera_info files: device/calibration/files.py; the calibration that
produces it: device/calibration/solve.py):

- ``image_size``: [width, height] of each camera's image, pixels;
- ``K1``, ``K2``: 3x3 camera matrices (pixels) of the left and right camera;
- ``D1``, ``D2``: distortion coefficients of ``distortion_model``;
- ``distortion_model``: ``"opencv"`` (OpenCV's pinhole model, coefficients k1, k2, p1, p2[, k3[, k4, k5,
  k6[, s1..s4[, tx, ty]]]], i.e. ROS ``plumb_bob`` / ``rational_polynomial``) or ``"equidistant"``
  (OpenCV's fisheye model, k1..k4: Kalibr's ``equidistant``, ROS ``equidistant``). A file without
  it means "opencv", except with four coefficients, which are ambiguous (k1, k2, p1, p2 or a
  fisheye's k1..k4) and must name the model;
- ``R``, ``T``: rotation (3x3) and translation (3, metres) taking left-camera coordinates to
  right-camera coordinates, ``X_right = R X_left + T`` (OpenCV's ``stereoCalibrate`` convention);
  the baseline is ``|T|``;
- ``rms``: stereo RMS reprojection error (pixels), ``rms_left`` / ``rms_right`` per camera;
- ``views``: per view name, corners used, errors (pixels) and whether it was used (and why not);
- ``board``: the ChArUco board (squares, square and marker size in metres, dictionary);
- ``created``: ISO 8601 UTC time;
- ``extra`` (optional): ``{"rectified": true}`` marks images that are already rectified (a dataset,
  or a camera that rectifies on board): the stereo-pair source then skips remapping and uses K1
  with ``|T|`` and the principal-point gap ``K2[0][2] - K1[0][2]`` as disparity offset.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import asdict, dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from measure import MeasureError, PinholeCamera

from device.calibration.board import BoardSpec
from device.calibration.storage import MAX_FILE_BYTES
from device.errors import CalibrationError

MAX_IMAGE_SIDE = 65536  # px; a calibration for larger images is a corrupt file (rectification maps would not fit)

FORMAT = "depthruler-stereo-calibration"
VERSION = 1
DISTORTION_MODELS = ("opencv", "equidistant")
# How far (largest entry) a file's R may be from the nearest rotation: a rotation printed with 4 or more
# decimals is off by at most 5e-5 and is used silently; up to ROTATION_FAR with a warning; beyond, refused.
ROTATION_WARN = 1e-4
ROTATION_FAR = 1e-2


class CalibrationWarning(UserWarning):
    """A calibration was read but something in it was repaired (R re-orthonormalised); the message says what."""


@dataclass(frozen=True)
class ViewResult:
    """How one view pair fared: corners seen by both cameras, reprojection errors (px), used or why not."""

    name: str
    corners: int
    error_left: float = math.nan
    error_right: float = math.nan
    error_stereo: float = math.nan
    used: bool = False
    reason: str = ""


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated stereo pair; see the module docstring for the meaning and units of each field."""

    image_size: tuple[int, int]
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    rms: float = math.nan
    rms_left: float = math.nan
    rms_right: float = math.nan
    views: tuple[ViewResult, ...] = ()
    board: BoardSpec | None = None
    created: str = ""
    extra: dict = field(default_factory=dict)
    distortion_model: str = "opencv"

    @property
    def baseline_m(self) -> float:
        return float(np.linalg.norm(self.T))

    def to_json(self) -> dict:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "format": FORMAT,
            "version": VERSION,
            "created": self.created or datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "K1": np.asarray(self.K1, float).tolist(),
            "D1": np.asarray(self.D1, float).ravel().tolist(),
            "K2": np.asarray(self.K2, float).tolist(),
            "D2": np.asarray(self.D2, float).ravel().tolist(),
            "distortion_model": self.distortion_model,
            "R": np.asarray(self.R, float).tolist(),
            "T": np.asarray(self.T, float).ravel().tolist(),
            "baseline_m": self.baseline_m,
            "rms": num(self.rms),
            "rms_left": num(self.rms_left),
            "rms_right": num(self.rms_right),
            "views": [
                {**asdict(v), **{k: num(getattr(v, k)) for k in ("error_left", "error_right", "error_stereo")}}
                for v in self.views
            ],
            "board": asdict(self.board) if self.board else None,
            **({"extra": self.extra} if self.extra else {}),
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(self.to_json(), indent=2) + "\n")
        tmp.replace(path)
        return path


def nearest_rotation(R: np.ndarray, source: str = "calibration") -> np.ndarray:
    """The rotation nearest to ``R`` (3x3) in the Frobenius norm: ``U V^T`` of its SVD ``U S V^T``.

    A matrix printed with a few decimals is no longer exactly orthonormal (5 decimals: entries off by up
    to 5e-6), so it is re-orthonormalised rather than refused; a :class:`CalibrationWarning` says so when
    an entry moves by more than ``ROTATION_WARN``, and a matrix that is no rotation (an entry off by more
    than ``ROTATION_FAR``, or a determinant <= 0) is a CalibrationError. A rotation to machine precision
    is returned as it is (a file written with all its digits reads back bit for bit).
    """
    U, _, Vt = np.linalg.svd(R)
    if np.linalg.det(R) <= 0:
        raise CalibrationError(f"{source}: R is not a rotation matrix: its determinant is {np.linalg.det(R):.4g}, a "
                               "rotation's is +1 (a negative one mirrors: is the field R, written row by row?)")
    near = U @ Vt  # det(R) > 0, so det(U V^T) = +1: a rotation, not a reflection
    moved = float(np.abs(near - R).max())
    if moved <= 1e-12:
        return R
    if moved > ROTATION_FAR:
        raise CalibrationError(f"{source}: R is not a rotation matrix: an entry is {moved:.3g} off the nearest rotation "
                               f"(up to {ROTATION_FAR:g} is repaired); check that R is the 3x3 rotation, row by row")
    if moved > ROTATION_WARN:
        warnings.warn(f"{source}: R is {moved:.2g} off a rotation (more than printing it rounds); "
                      "using the nearest rotation", CalibrationWarning, stacklevel=3)
    return near


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a calibration file written by :meth:`StereoCalibration.save` (or by hand, same format)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(
            f"calibration file {str(path)!r} does not exist; create it with "
            "`depthruler calibrate --images DIR --out FILE` or fix the calib= path"
        )
    if path.stat().st_size > MAX_FILE_BYTES:
        raise CalibrationError(f"calibration file {str(path)!r} has {path.stat().st_size} bytes; a calibration has a few "
                               f"thousand (at most {MAX_FILE_BYTES}): is it the right file?")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise CalibrationError(f"calibration file {str(path)!r} is not valid JSON ({exc}); recreate it") from exc
    return calibration_from_json(data, source=str(path))


def calibration_from_json(data: dict, source: str = "calibration") -> StereoCalibration:
    """Validate and convert the JSON form; every error names the field and what it should be."""
    if not isinstance(data, dict):
        raise CalibrationError(f"{source}: expected a JSON object with K1, D1, K2, D2, R, T, image_size")
    if data.get("format", FORMAT) != FORMAT:
        raise CalibrationError(f"{source}: format {data.get('format')!r} is not {FORMAT!r}")
    version = data.get("version", VERSION)
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise CalibrationError(f"{source}: version {version!r} must be a whole number >= 1 (this depthruler writes {VERSION})")
    if version > VERSION:
        raise CalibrationError(f"{source}: version {version} is newer than this depthruler reads ({VERSION})")

    def arr(name: str, shape: tuple[int, ...] | None, sizes: tuple[int, ...] = ()) -> np.ndarray:
        if name not in data:
            raise CalibrationError(f"{source}: field {name!r} is missing")
        try:
            a = np.asarray(data[name], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"{source}: field {name!r} must be numbers") from exc
        if shape is not None and a.shape != shape:
            raise CalibrationError(f"{source}: field {name!r} must have shape {shape}, got {a.shape}")
        if sizes and a.size not in sizes:
            raise CalibrationError(f"{source}: field {name!r} must have {' or '.join(map(str, sizes))} numbers")
        if not np.all(np.isfinite(a)):
            raise CalibrationError(f"{source}: field {name!r} contains non-finite numbers")
        return a

    size = arr("image_size", (2,))
    if np.any(size < 1) or np.any(size > MAX_IMAGE_SIDE) or np.any(size != np.round(size)):
        raise CalibrationError(
            f"{source}: image_size must be two whole numbers of pixels in 1..{MAX_IMAGE_SIDE}, got {size.tolist()}"
        )
    K1, K2 = arr("K1", (3, 3)), arr("K2", (3, 3))
    for name, K in (("K1", K1), ("K2", K2)):
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
            raise CalibrationError(f"{source}: {name} is not a camera matrix [[fx,0,cx],[0,fy,cy],[0,0,1]]")
    model = data.get("distortion_model")
    if model is not None and model not in DISTORTION_MODELS:
        raise CalibrationError(f"{source}: distortion_model {model!r} is unknown; use one of {', '.join(DISTORTION_MODELS)}")
    for name, K in (("K1", K1), ("K2", K2)):
        try:  # the same physical ranges as every frame's camera (measure.types.validate_camera)
            PinholeCamera(fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2], width=int(size[0]), height=int(size[1]))
        except MeasureError as exc:
            raise CalibrationError(f"{source}: {name}: {exc}") from None
    dist_sizes = (4,) if model == "equidistant" else (4, 5, 8, 12, 14)
    D1, D2 = arr("D1", None, dist_sizes).ravel(), arr("D2", None, dist_sizes).ravel()
    if model is None and D1.size == 4:
        raise CalibrationError(
            f"{source}: four distortion coefficients are ambiguous (OpenCV k1,k2,p1,p2 or a fisheye's k1..k4, "
            "e.g. Kalibr's equidistant); name the model: distortion_model \"opencv\" or \"equidistant\" "
            "(source spec: distortion=opencv|equidistant)"
        )
    R = nearest_rotation(arr("R", (3, 3)), source)
    T = arr("T", None, (3,)).reshape(3)
    if np.abs(T).max() > 5:  # before the norm: its squares could overflow
        raise CalibrationError(f"{source}: T = {T.tolist()} is implausible; T must be in metres "
                               "(a file with T in mm: add calib_units=mm to the source spec)")
    if np.linalg.norm(T) <= 0:
        raise CalibrationError(f"{source}: T is zero; the two cameras must be apart (T in metres)")
    if np.linalg.norm(T) > 5:
        raise CalibrationError(f"{source}: |T| = {np.linalg.norm(T):.1f} m is implausible; T must be in metres "
                               "(a file with T in mm: add calib_units=mm to the source spec)")
    board = data.get("board")
    view_fields = {f.name for f in fields(ViewResult)}
    try:
        views = tuple(
            ViewResult(**{k: (math.nan if x is None and k.startswith("error") else x)
                          for k, x in v.items() if k in view_fields})
            for v in data.get("views", [])
        )
        board = BoardSpec(**board) if isinstance(board, dict) else None
    except (TypeError, AttributeError, ValueError, CalibrationError, cv2.error) as exc:
        raise CalibrationError(f"{source}: 'views' or 'board' is malformed ({exc}); recreate the file") from exc

    def num(key: str) -> float:
        v = data.get(key)
        if v is None:
            return math.nan
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise CalibrationError(f"{source}: field {key!r} must be a number or null, got {v!r}")
        return float(v)

    extra = data.get("extra", {})
    if not isinstance(extra, dict):
        raise CalibrationError(f"{source}: field 'extra' must be a JSON object, got {type(extra).__name__}")

    return StereoCalibration(
        image_size=(int(size[0]), int(size[1])),
        K1=K1,
        D1=D1,
        K2=K2,
        D2=D2,
        R=R,
        T=T,
        rms=num("rms"),
        rms_left=num("rms_left"),
        rms_right=num("rms_right"),
        views=views,
        board=board,
        created=str(data.get("created", "")),
        extra=dict(extra),
        distortion_model=model or "opencv",
    )
