"""Stereo calibration in the files people already have: OpenCV FileStorage and ROS camera_info.

Read by :class:`CalibrationRef` (what a source spec's ``calib=`` names) and written by
``depthruler calibrate --format``; the project's JSON (device/calibration/stereo.py) stays the native form
and every file is validated through it. Conventions:

- **OpenCV FileStorage** (``.yaml``/``.yml``/``.xml``, as OpenCV's stereo calibration samples write
  them; the intrinsics and extrinsics may be two files: ``calib=intrinsics.yml,extrinsics.yml``):
  ``M1``/``K1``/``cameraMatrix1``, ``D1``/``distCoeffs1``, the same with 2 for the right camera,
  ``R`` and ``T`` with ``X_right = R X_left + T``, and the image size as ``image_size``/``imageSize``
  ([w, h]) or ``image_width`` + ``image_height`` (the samples do not write it: add it). ``T`` is in the
  unit of the board's square size given to the calibration: the file's ``units`` (e.g. ``"mm"``) or the
  spec's ``calib_units`` (m, cm, mm, in, or squares with ``calib_square_mm``); without either, metres, and a
  ``|T|`` outside a stereo baseline (1 cm - 0.5 m) is refused, naming the likely unit. The distortion model is OpenCV's pinhole model
  unless the file has ``distortion_model`` (or the spec ``distortion=equidistant``); four coefficients
  without a model are refused (device/calibration/stereo.py).
- **ROS camera_info pair** (``calib=left.yaml,right.yaml``, camera_calibration_parsers' YAML):
  ``camera_matrix`` K, ``distortion_model`` (``plumb_bob``/``rational_polynomial`` = opencv,
  ``equidistant`` = fisheye), ``distortion_coefficients``, ``rectification_matrix`` R_rect and
  ``projection_matrix`` P. ROS stores the stereo extrinsics through the rectification: with
  ``X_rect_l = R_rect_l X_l`` and ``X_rect_r = R_rect_r X_r = X_rect_l + (Tx / fx', 0, 0)``
  (``Tx = P_r[0, 3]``, ``fx' = P_r[0, 0]``), the pair's ``R = R_rect_r^T R_rect_l`` and
  ``T = R_rect_r^T (Tx / fx', 0, 0)``. ROS works in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from measure import check_options, option

from device.calibration.storage import read_storage
from device.calibration.stereo import DISTORTION_MODELS, MAX_IMAGE_SIDE, StereoCalibration, calibration_from_json, load_calibration
from device.errors import CalibrationError

# Metres per unit of T; "squares" (the board's square side, given by calib_square_mm) is what OpenCV's
# stereo_calib sample writes when run with its default square size of 1.
UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "in": 0.0254, "squares": math.nan}
BASELINE_M = (0.01, 0.5)  # a stereo camera's baseline: T in a file without units must give one in this range
SQUARE_MM = (10.0, 100.0)  # printed board squares, for the guess whether T is in squares
FORMATS = ("json", "opencv-yaml", "opencv-xml", "ros")
ROS_MODELS = {"plumb_bob": "opencv", "rational_polynomial": "opencv", "equidistant": "equidistant"}
_ALIASES = {
    "K1": ("K1", "M1", "cameraMatrix1", "camera_matrix_left"),
    "D1": ("D1", "distCoeffs1", "dist_coeffs_left"),
    "K2": ("K2", "M2", "cameraMatrix2", "camera_matrix_right"),
    "D2": ("D2", "distCoeffs2", "dist_coeffs_right"),
    "R": ("R",),
    "T": ("T",),
}


@dataclass(frozen=True)
class CalibrationRef:
    """The calibration a source spec names: file(s), the unit of T in them, the distortion model."""

    path: str = option("", key="calib", example="rig.json", help="calibration: the project's JSON, OpenCV YAML/XML, or a ROS pair left.yaml,right.yaml")
    units: str | None = option(None, key="calib_units", choices=tuple(UNITS), default_text="the file's, else m",
                               help="unit of T in an OpenCV or ROS file (squares: with calib_square_mm)")
    square_mm: float | None = option(None, key="calib_square_mm", min=0.0, min_open=True, unit="mm",
                                     help="the board's square side when calib_units=squares")
    distortion_model: str | None = option(None, key="distortion", choices=DISTORTION_MODELS,
                                          default_text="the file's", help="lens model of an OpenCV file without one")

    def __post_init__(self) -> None:
        check_options(self, CalibrationError)

    def load(self) -> StereoCalibration:
        if not self.path:
            raise CalibrationError(
                "a stereo pair needs its calibration: add calib=FILE to the source spec (project .json, OpenCV "
                ".yaml/.xml, or a ROS camera_info pair left.yaml,right.yaml); create one with "
                "`depthruler calibrate --images DIR --out FILE.json`"
            )
        return load_any(self.path, units=self.units, square_mm=self.square_mm, distortion_model=self.distortion_model)


def load_any(ref: str, *, units: str | None = None, square_mm: float | None = None,
             distortion_model: str | None = None) -> StereoCalibration:
    """A calibration from the project's JSON, OpenCV FileStorage file(s) or a ROS camera_info pair.

    ``units``: the unit of T (:data:`UNITS`; None: the file's ``units``, else metres, and then a ``|T|``
    outside :data:`BASELINE_M` is refused, naming the units that would give a baseline);
    ``square_mm``: the board's square side (mm) for ``units="squares"``.
    """
    paths = [Path(p.strip()) for p in ref.split(",") if p.strip()]
    for p in paths:
        if not p.is_file():
            raise CalibrationError(f"calibration file {str(p)!r} does not exist; fix the calib= path")
    if len(paths) == 1 and paths[0].suffix.lower() == ".json":
        if units not in (None, "m") or square_mm is not None or distortion_model:
            raise CalibrationError(f"{paths[0]}: the project's JSON is in metres with its distortion model "
                                   "inside; drop calib_units/distortion from the spec")
        return load_calibration(paths[0])
    nodes = [read_storage(p) for p in paths]
    if len(nodes) == 2 and all("camera_matrix" in n for n in nodes):
        data = _from_ros(nodes[0], nodes[1], " + ".join(map(str, paths)))
    elif any("camera_matrix" in n for n in nodes):
        raise CalibrationError(f"{ref}: a ROS camera_info calibration needs both cameras: calib=left.yaml,right.yaml")
    else:
        merged: dict = {}
        for n in nodes:
            merged.update(n)
        data = _from_opencv(merged, ref)
    given = data.pop("units", None)
    unit = units or (None if given is None else str(given))
    if unit is not None and unit not in UNITS:
        raise CalibrationError(f"{ref}: units {unit!r} is unknown; use one of {', '.join(UNITS)}")
    if (unit == "squares") != (square_mm is not None):
        raise CalibrationError(f"{ref}: T in board squares needs the square side: give calib_units=squares together "
                               "with calib_square_mm=SIDE (the printed square in mm, measured with a ruler)")
    T = np.asarray(data["T"], np.float64).ravel()
    if unit is None:
        _check_baseline(T, ref)
    data["T"] = (T * (square_mm * 1e-3 if unit == "squares" else UNITS[unit or "m"])).tolist()
    if distortion_model:
        data["distortion_model"] = distortion_model
    return calibration_from_json(data, source=ref)


def _check_baseline(T: np.ndarray, source: str) -> None:
    """CalibrationError when T, read in metres for want of a unit, is no stereo baseline (:data:`BASELINE_M`):
    the message gives the baseline each unit would give and names those that give a plausible one."""
    if T.size != 3 or not np.all(np.isfinite(T)) or np.abs(T).max() > 1e12:
        return  # calibration_from_json names what is wrong with T itself
    norm = float(np.linalg.norm(T))
    lo, hi = BASELINE_M
    if norm == 0 or lo <= norm <= hi:
        return
    each = [f"{u} {_length(norm * UNITS[u])}" for u in UNITS if u != "squares"]
    likely = [u for u in UNITS if u != "squares" and lo <= norm * UNITS[u] <= hi]
    if SQUARE_MM[0] * 1e-3 * norm <= hi and SQUARE_MM[1] * 1e-3 * norm >= lo:
        likely.append("squares")
    each.append(f"squares {norm:.3g} x the square side ({_length(norm * 0.025)} with 25 mm squares; OpenCV's "
                "stereo_calib sample writes T in squares unless given the square size)")
    fix = (f"the likely unit is {' or '.join(likely)}: add calib_units={'|'.join(likely)} to the source spec"
           + (" (squares with calib_square_mm=SIDE, the printed square in mm)" if "squares" in likely else "")
           if likely else "no unit gives a plausible baseline: check T")
    raise CalibrationError(
        f"{source}: |T| = {norm:.4g} and the file gives no unit; in metres the baseline would be {_length(norm)}, outside "
        f"a stereo camera's {_length(lo)} - {_length(hi)}. As each unit: {', '.join(each)}. {fix[0].upper()}{fix[1:]} "
        f"(or units: to the file); calib_units=m if {_length(norm)} is right"
    )


def _length(m: float) -> str:
    return f"{m * 1000:.3g} mm" if m < 1 else f"{m:.3g} m"


def _matrix(value, source: str, name: str) -> np.ndarray:
    """A finite float matrix from an opencv-matrix, a ROS {rows, cols, data} map or a (nested) list of
    numbers; CalibrationError naming the field otherwise."""
    if isinstance(value, dict) and "data" in value:
        data = value["data"]
        flat = _numbers(data if isinstance(data, list) else [data], source, f"{name}.data")
        r, c = (_whole(value.get(k, default), source, f"{name}.{k}") for k, default in (("rows", 1), ("cols", flat.size)))
        if r * c != flat.size:
            raise CalibrationError(f"{source}: field {name} says {r}x{c} but its data holds {flat.size} numbers")
        a = flat.reshape(r, c)
    elif isinstance(value, np.ndarray):
        a = value.astype(np.float64)
    else:
        rows_in = value if isinstance(value, list) and value and all(isinstance(v, list) for v in value) else [value]
        if len({len(r) if isinstance(r, list) else 1 for r in rows_in}) != 1:
            raise CalibrationError(f"{source}: field {name} has rows of different lengths")
        a = np.array([_numbers(r if isinstance(r, list) else [r], source, name) for r in rows_in], np.float64)
        a = a if len(rows_in) > 1 else a.ravel()
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{source}: field {name} holds a value that is not a finite number")
    return a


def _numbers(items: list, source: str, name: str) -> np.ndarray:
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
        raise CalibrationError(f"{source}: field {name} must hold numbers only, got {items[:6]!r}")
    return np.asarray(items, np.float64)


def _whole(value, source: str, name: str, top: int = MAX_IMAGE_SIDE) -> int:
    """A whole number 1..top from a number (or a numeric string), or CalibrationError naming the field."""
    try:
        v = float(value) if not isinstance(value, bool) else math.nan
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v == round(v) and 1 <= v <= top):
        raise CalibrationError(f"{source}: field {name} must be a whole number 1..{top}, got {value!r}")
    return int(v)


def _image_size(d: dict, source: str) -> list[int]:
    for key in ("image_size", "imageSize", "size"):
        if key in d:
            wh = _matrix(d[key], source, key).ravel()
            if wh.size != 2:
                raise CalibrationError(f"{source}: field {key} must be [width, height] in pixels, got {wh.tolist()}")
            return [_whole(v, source, key) for v in wh]
    for w, h in (("image_width", "image_height"), ("width", "height"), ("imageWidth", "imageHeight")):
        if w in d and h in d:
            return [_whole(d[w], source, w), _whole(d[h], source, h)]
    raise CalibrationError(
        f"{source}: the image size is missing; add image_width and image_height (pixels of one camera's image "
        "at calibration) to the file: OpenCV's stereo_calib sample does not write them"
    )


def _from_opencv(d: dict, source: str) -> dict:
    out: dict = {}
    for field, names in _ALIASES.items():
        found = next((n for n in names if n in d and d[n] is not None), None)
        if found is None:
            raise CalibrationError(f"{source}: no {' / '.join(names)} in the file (OpenCV stereo calibration needs "
                                   "M1, D1, M2, D2, R, T and the image size)")
        out[field] = _matrix(d[found], source, found).tolist()
    R = np.asarray(out["R"], np.float64)
    if R.size == 3:  # a Rodrigues vector, as some tools write R
        out["R"] = cv2.Rodrigues(R.reshape(3, 1))[0].tolist()
    elif R.size != 9:
        raise CalibrationError(f"{source}: field R has {R.size} numbers; it must be a 3x3 rotation or a Rodrigues 3-vector")
    out["image_size"] = _image_size(d, source)
    if "distortion_model" in d:
        out["distortion_model"] = ROS_MODELS.get(str(d["distortion_model"]), str(d["distortion_model"]))
    if "units" in d:
        out["units"] = str(d["units"])
    return out


def _from_ros(left: dict, right: dict, source: str) -> dict:
    models = {str(c.get("distortion_model", "")) for c in (left, right)}
    if len(models) != 1 or next(iter(models)) not in ROS_MODELS:
        raise CalibrationError(f"{source}: distortion_model {sorted(models)} must be one of "
                               f"{', '.join(ROS_MODELS)} and the same for both cameras")
    sizes = [_image_size(c, source) for c in (left, right)]
    if sizes[0] != sizes[1]:
        raise CalibrationError(f"{source}: the cameras have different image sizes {sizes[0]} and {sizes[1]}")
    try:
        K1, K2 = (_ros_matrix(c, "camera_matrix", source, (3, 3)) for c in (left, right))
        R1, R2 = (_ros_matrix(c, "rectification_matrix", source, (3, 3)) for c in (left, right))
        P2 = _ros_matrix(right, "projection_matrix", source, (3, 4))
        D1, D2 = (_matrix(c["distortion_coefficients"], source, "distortion_coefficients").ravel() for c in (left, right))
    except KeyError as exc:
        raise CalibrationError(f"{source}: camera_info field {exc} is missing") from exc
    if not P2[0, 0] > 0:
        raise CalibrationError(f"{source}: the right camera's projection_matrix has fx' = {P2[0, 0]:g}; it must be > 0")
    if abs(P2[0, 3]) <= 0:
        raise CalibrationError(f"{source}: the right camera's projection_matrix has Tx = 0; the files are not "
                               "a calibrated stereo pair (left first, then right)")
    T = R2.T @ np.array([P2[0, 3] / P2[0, 0], 0.0, 0.0])
    return {
        "image_size": sizes[0], "K1": K1.tolist(), "K2": K2.tolist(), "D1": D1.tolist(), "D2": D2.tolist(),
        "R": (R2.T @ R1).tolist(), "T": T.tolist(), "distortion_model": ROS_MODELS[next(iter(models))],
    }


def _ros_matrix(camera: dict, key: str, source: str, shape: tuple[int, int]) -> np.ndarray:
    a = _matrix(camera[key], source, key)
    if a.size != shape[0] * shape[1]:
        raise CalibrationError(f"{source}: field {key} has {a.size} numbers; it must be {shape[0]}x{shape[1]}")
    return a.reshape(shape)


def write(calib: StereoCalibration, out: str | Path, fmt: str) -> list[Path]:
    """Write ``calib`` as ``fmt`` (:data:`FORMATS`); returns the files written.

    ``ros`` writes ``OUT_left.yaml`` and ``OUT_right.yaml`` (OUT without its suffix), with the
    rectification and projection of ``cv2.stereoRectify`` (zero disparity, alpha 0) at the image size.
    """
    out = Path(out)
    if fmt not in FORMATS:
        raise CalibrationError(f"format {fmt!r} is unknown; use one of {', '.join(FORMATS)}")
    out.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "json":
        return [calib.save(out)]
    if fmt in ("opencv-yaml", "opencv-xml"):
        suffix = ".xml" if fmt == "opencv-xml" else out.suffix if out.suffix in (".yaml", ".yml") else ".yaml"
        path = out.with_suffix(suffix)
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.writeComment("depthruler stereo calibration: X_right = R X_left + T, T in metres")
        fs.write("image_width", int(calib.image_size[0]))
        fs.write("image_height", int(calib.image_size[1]))
        for name in ("K1", "D1", "K2", "D2", "R"):
            fs.write(name, np.asarray(getattr(calib, name), np.float64).reshape(3, -1) if name[0] in "KR"
                     else np.asarray(getattr(calib, name), np.float64).reshape(1, -1))
        fs.write("T", np.asarray(calib.T, np.float64).reshape(3, 1))
        fs.write("units", "m")
        fs.write("distortion_model", calib.distortion_model)
        fs.release()
        return [path]
    return _write_ros(calib, out)


def _write_ros(calib: StereoCalibration, out: Path) -> list[Path]:
    w, h = calib.image_size
    T = np.asarray(calib.T, np.float64).reshape(3, 1)
    if calib.distortion_model == "equidistant":
        R1, R2, P1, P2, _Q = cv2.fisheye.stereoRectify(calib.K1, calib.D1, calib.K2, calib.D2, (w, h), calib.R, T,
                                                       cv2.CALIB_ZERO_DISPARITY, balance=0.0)
        model = "equidistant"
    else:
        R1, R2, P1, P2, *_ = cv2.stereoRectify(calib.K1, calib.D1, calib.K2, calib.D2, (w, h), calib.R, T,
                                               flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
        model = "plumb_bob" if np.asarray(calib.D1).size <= 5 else "rational_polynomial"
        if np.asarray(calib.D1).size < 5:  # plumb_bob has five coefficients; k3 = 0 is the same model
            calib = replace(calib, D1=np.pad(np.ravel(calib.D1), (0, 1)), D2=np.pad(np.ravel(calib.D2), (0, 1)))
    paths = []
    stem = out.with_suffix("")
    for side, K, D, Rr, P in (("left", calib.K1, calib.D1, R1, P1), ("right", calib.K2, calib.D2, R2, P2)):
        def mat(a: np.ndarray, rows: int) -> str:
            a = np.asarray(a, np.float64).reshape(rows, -1)
            data = ", ".join(repr(float(v)) for v in a.ravel())
            return f"\n  rows: {rows}\n  cols: {a.shape[1]}\n  data: [{data}]"

        text = (f"image_width: {w}\nimage_height: {h}\ncamera_name: {side}\ncamera_matrix:{mat(K, 3)}\n"
                f"distortion_model: {model}\ndistortion_coefficients:{mat(D, 1)}\n"
                f"rectification_matrix:{mat(Rr, 3)}\nprojection_matrix:{mat(P, 3)}\n")
        path = Path(f"{stem}_{side}.yaml")
        path.write_text(text)
        paths.append(path)
    return paths
