"""Stereo calibration of a two-camera rig with a ChArUco board, and its JSON calibration file.

Procedure (OpenCV 5 API):
1. detect the board in every view pair (``CharucoDetector.detectBoard``) and keep the corners
   seen by both cameras;
2. calibrate each camera alone (``calibrateCamera`` on those matched points), compute each
   view's reprojection error and reject views worse than ``reject_factor`` x the median (a blurred
   or mis-detected view) or with too few corners, then recalibrate;
3. ``stereoCalibrate`` with the intrinsics fixed (OpenCV 5's default ``CALIB_FIX_INTRINSIC``),
   reject views whose stereo error is an outlier the same way (e.g. a pair captured out of sync)
   and solve again.

The project's native calibration file (JSON, ``FORMAT`` / ``VERSION``), read by :func:`load_calibration`
(OpenCV FileStorage and ROS camera_info files are read and written by device/calibration/files.py):

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
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np

from measure import MeasureError, PinholeCamera

from device.errors import CalibrationError

MAX_IMAGE_SIDE = 65536  # px; a calibration for larger images is a corrupt file (rectification maps would not fit)

FORMAT = "depthruler-stereo-calibration"
VERSION = 1
DISTORTION_MODELS = ("opencv", "equidistant")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

Progress = Callable[[str], None]


class PairGrabber(Protocol):
    """Where calibration views come from (same shape as ``stereo_pair.FrameGrabber``)."""

    def open(self) -> None: ...

    def grab(self, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across and down, square and marker side in metres, ArUco dictionary."""

    squares_x: int = 11
    squares_y: int = 8
    square_m: float = 0.030
    marker_m: float = 0.022
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3:
            raise CalibrationError(f"board {self.squares_x}x{self.squares_y} squares is too small; use at least 3x3")
        if not (0 < self.marker_m < self.square_m):
            raise CalibrationError(
                f"marker side {self.marker_m} m must be positive and smaller than the square side {self.square_m} m"
            )
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(f"unknown ArUco dictionary {self.dictionary!r}; use e.g. DICT_5X5_100, DICT_4X4_50")

    def board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, dictionary)

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)


def write_board_png(board: BoardSpec, out: str | Path, dpi: float = 300.0, margin_mm: float = 10.0) -> tuple[Path, float, float]:
    """Write the printable ChArUco board that :func:`calibrate_stereo` expects; returns (path, width mm, height mm).

    The PNG is rendered at ``dpi`` with a white margin of ``margin_mm`` around the squares and
    carries its physical resolution (a pHYs chunk), so printing at 100 % ("actual size") gives
    squares of ``board.square_m``. The returned size is the whole sheet, margins included.
    """
    import struct
    import zlib

    if not (72 <= dpi <= 1200):
        raise CalibrationError(f"dpi={dpi} must lie in 72..1200")
    # Whole pixels per square, and the PNG's resolution set from them, so a square prints at exactly
    # its size (the effective dpi differs from the asked one by less than half a pixel per square).
    square_px = int(round(board.square_m * 1000.0 * dpi / 25.4))
    px_per_mm = square_px / (board.square_m * 1000.0)
    margin_px = int(round(margin_mm * px_per_mm))
    w = board.squares_x * square_px + 2 * margin_px
    h = board.squares_y * square_px + 2 * margin_px
    image = board.board().generateImage((w, h), marginSize=margin_px, borderBits=1)
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise CalibrationError("OpenCV could not encode the board as PNG")
    data = png.tobytes()
    ppm = int(round(px_per_mm * 1000.0))
    body = b"pHYs" + struct.pack(">IIB", ppm, ppm, 1)  # pixels per metre, unit = metre
    chunk = struct.pack(">I", 9) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)
    ihdr_end = 8 + 8 + 13 + 4  # signature, IHDR length + type, IHDR data, CRC
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(data[:ihdr_end] + chunk + data[ihdr_end:])
    return out, w / px_per_mm, h / px_per_mm


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


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a calibration file written by :meth:`StereoCalibration.save` (or by hand, same format)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(
            f"calibration file {str(path)!r} does not exist; create it with "
            "`depthruler calibrate --images DIR --out FILE` or fix the calib= path"
        )
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
    R = arr("R", (3, 3))
    if np.abs(R).max() > 1 + 1e-6 or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise CalibrationError(f"{source}: R is not a rotation matrix (orthonormal with determinant +1)")
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


@dataclass(frozen=True)
class Detection:
    """Board corners found in one image: ids into the board's chessboard corners, pixel positions."""

    ids: np.ndarray  # (N,) int
    corners: np.ndarray  # (N, 2) float32 pixels


def detect_board(detector: cv2.aruco.CharucoDetector, image: np.ndarray) -> Detection | None:
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners, ids, _, _ = detector.detectBoard(gray)
    if corners is None or ids is None or len(ids) == 0:
        return None
    return Detection(ids=np.asarray(ids).ravel().astype(np.int32), corners=np.asarray(corners, np.float32).reshape(-1, 2))


def _view_errors(obj, img, K, D, rvecs, tvecs) -> np.ndarray:
    errs = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, K, D)
        errs.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - i.reshape(-1, 2)) ** 2, axis=1)))))
    return np.asarray(errs)


def _outliers(errors: np.ndarray, factor: float, floor_px: float) -> np.ndarray:
    # A floor keeps a uniformly excellent set (synthetic, 0.05 px) from losing views to noise.
    return errors > max(factor * float(np.median(errors)), floor_px)


def calibrate_stereo(
    views: Iterable[tuple[str, np.ndarray, np.ndarray]],
    board: BoardSpec = BoardSpec(),
    *,
    min_corners: int = 12,
    min_views: int = 6,
    reject_factor: float = 3.0,
    reject_floor_px: float = 0.5,
    progress: Progress | None = None,
) -> StereoCalibration:
    """Calibrate a stereo pair from (name, left image, right image) views of a ChArUco board.

    Images are BGR or grey, all of one size. See the module docstring for the procedure.
    Raises :class:`CalibrationError` naming what to fix when too few usable views remain.
    """
    say = progress or (lambda _msg: None)
    cb = board.board()
    detector = cv2.aruco.CharucoDetector(cb)
    all_obj = cb.getChessboardCorners().astype(np.float32)
    results: dict[str, ViewResult] = {}
    names, obj_pts, left_pts, right_pts = [], [], [], []
    size: tuple[int, int] | None = None
    views = list(views)
    if not views:
        raise CalibrationError("no view pairs given; point --images at a folder of left/right image pairs")
    for k, (name, left, right) in enumerate(views, 1):
        for img, side in ((left, "left"), (right, "right")):
            if img is None or img.ndim not in (2, 3):
                raise CalibrationError(f"view {name}: the {side} image is missing or not an image")
        if left.shape[:2] != right.shape[:2]:
            raise CalibrationError(f"view {name}: left is {left.shape[1]}x{left.shape[0]} but right is "
                                   f"{right.shape[1]}x{right.shape[0]}; both cameras must use one size")
        this = (left.shape[1], left.shape[0])
        if size is None:
            size = this
        elif this != size:
            raise CalibrationError(f"view {name} is {this[0]}x{this[1]} but earlier views are {size[0]}x{size[1]}")
        dl, dr = detect_board(detector, left), detect_board(detector, right)
        common = np.intersect1d(dl.ids, dr.ids) if dl is not None and dr is not None else np.empty(0, np.int32)
        if len(common) < min_corners:
            seen = f"{0 if dl is None else len(dl.ids)} left / {0 if dr is None else len(dr.ids)} right"
            results[name] = ViewResult(name, int(len(common)), reason=f"too few corners seen by both ({seen})")
            say(f"[{k}/{len(views)}] {name}: rejected, {results[name].reason}")
            continue
        pos_l = {int(i): j for j, i in enumerate(dl.ids)}
        pos_r = {int(i): j for j, i in enumerate(dr.ids)}
        il, ir = [pos_l[int(i)] for i in common], [pos_r[int(i)] for i in common]
        names.append(name)
        obj_pts.append(all_obj[common])
        left_pts.append(dl.corners[il])
        right_pts.append(dr.corners[ir])
        results[name] = ViewResult(name, int(len(common)))
        say(f"[{k}/{len(views)}] {name}: {len(common)} corners")

    def need(n: int, stage: str) -> None:
        if n < min_views:
            raise CalibrationError(
                f"only {n} usable views {stage} (need {min_views}); capture more pairs with the whole board "
                f"sharp and visible to both cameras at varied angles and distances; board {board.squares_x}x"
                f"{board.squares_y} squares {board.dictionary} must match the printed one"
            )

    need(len(names), "with the board seen by both cameras")
    keep = np.ones(len(names), bool)
    for last in (False, False, True):
        idx = np.flatnonzero(keep)
        need(len(idx), "after rejecting bad views")
        cams = []
        for pts in (left_pts, right_pts):
            rms, K, D, rv, tv = cv2.calibrateCamera([obj_pts[i] for i in idx], [pts[i] for i in idx], size, None, None)
            cams.append((rms, K, D, _view_errors([obj_pts[i] for i in idx], [pts[i] for i in idx], K, D, rv, tv)))
        bad = _outliers(cams[0][3], reject_factor, reject_floor_px) | _outliers(cams[1][3], reject_factor,
                                                                                 reject_floor_px)
        for j, i in enumerate(idx):
            results[names[i]] = ViewResult(names[i], len(obj_pts[i]), cams[0][3][j], cams[1][3][j])
        if last or not bad.any():
            break
        for j in np.flatnonzero(bad):
            i = idx[j]
            v = results[names[i]]
            results[names[i]] = ViewResult(v.name, v.corners, v.error_left, v.error_right,
                                           reason=f"reprojection error {max(v.error_left, v.error_right):.2f} px "
                                                  f"> {reject_factor:g}x median")
            say(f"{names[i]}: rejected, {results[names[i]].reason}")
        keep[idx[bad]] = False
    (rms_l, K1, D1, _), (rms_r, K2, D2, _) = cams
    say(f"left camera: RMS {rms_l:.3f} px, fx {K1[0, 0]:.1f}; right camera: RMS {rms_r:.3f} px, fx {K2[0, 0]:.1f}")

    for last in (False, False, True):
        idx = np.flatnonzero(keep)
        need(len(idx), "for the stereo solve")
        rms, K1, D1, K2, D2, R, T, _E, _F, _rv, _tv, per_view = cv2.stereoCalibrateExtended(
            [obj_pts[i] for i in idx], [left_pts[i] for i in idx], [right_pts[i] for i in idx],
            K1, D1, K2, D2, size, None, None, flags=cv2.CALIB_FIX_INTRINSIC,
        )
        stereo_err = np.sqrt(np.mean(np.asarray(per_view, float).reshape(len(idx), 2) ** 2, axis=1))
        for j, i in enumerate(idx):
            v = results[names[i]]
            results[names[i]] = ViewResult(v.name, v.corners, v.error_left, v.error_right, float(stereo_err[j]), True)
        bad = _outliers(stereo_err, reject_factor, reject_floor_px)
        if last or not bad.any():
            break
        for j in np.flatnonzero(bad):
            v = results[names[idx[j]]]
            results[v.name] = ViewResult(v.name, v.corners, v.error_left, v.error_right, v.error_stereo, False,
                                         f"stereo error {v.error_stereo:.2f} px > {reject_factor:g}x median "
                                         "(pair out of sync?)")
            say(f"{v.name}: rejected, {results[v.name].reason}")
        keep[idx[bad]] = False
    T = T.reshape(3)
    say(f"stereo: RMS {rms:.3f} px over {int(keep.sum())} views, baseline {np.linalg.norm(T) * 1000:.2f} mm")
    return StereoCalibration(
        image_size=size,
        K1=K1, D1=D1.ravel(), K2=K2, D2=D2.ravel(), R=R, T=T,
        rms=float(rms), rms_left=float(rms_l), rms_right=float(rms_r),
        views=tuple(results[n] for n, _, _ in views),
        board=board,
        created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
    )


def load_image_pairs(folder: str | Path, *, side_by_side: bool = False) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """View pairs from a folder, in name order. Accepted layouts:

    - ``left/NAME.png`` and ``right/NAME.png`` (same names);
    - ``NAME_left.png`` / ``NAME_right.png`` (also ``left_NAME`` / ``right_NAME``, ``L``/``R``-free names);
    - with ``side_by_side``: each image holds left | right halves (one UVC stereo camera).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CalibrationError(f"image folder {str(folder)!r} does not exist")

    def images(d: Path) -> list[Path]:
        return sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)

    def read(p: Path) -> np.ndarray:
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            raise CalibrationError(f"cannot read image {str(p)!r}; is it a valid PNG/JPEG?")
        return img

    if side_by_side:
        out = []
        for p in images(folder):
            img = read(p)
            if img.shape[1] % 2:
                raise CalibrationError(f"{p.name} is {img.shape[1]} px wide; a side-by-side image has an even width")
            half = img.shape[1] // 2
            out.append((p.stem, img[:, :half], img[:, half:]))
        if not out:
            raise CalibrationError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in {str(folder)!r}")
        return out
    if (folder / "left").is_dir() and (folder / "right").is_dir():
        lefts = {p.stem: p for p in images(folder / "left")}
        rights = {p.stem: p for p in images(folder / "right")}
    else:
        lefts, rights = {}, {}
        for p in images(folder):
            stem = p.stem
            for tag, bucket in (("left", lefts), ("right", rights)):
                if tag in stem.lower():
                    i = stem.lower().index(tag)
                    bucket[(stem[:i] + stem[i + len(tag):]).strip("_-. ")] = p
    common = sorted(set(lefts) & set(rights))
    if not common:
        raise CalibrationError(
            f"no left/right image pairs in {str(folder)!r}: use left/NAME.png + right/NAME.png, "
            "NAME_left.png + NAME_right.png, or --side-by-side for combined images"
        )
    return [(name, read(lefts[name]), read(rights[name])) for name in common]


def render_board_view(
    board_image: np.ndarray,
    pixels_per_m: float,
    margin_px: int,
    K: np.ndarray,
    rvec: Sequence[float],
    tvec: Sequence[float],
    size: tuple[int, int],
    background: int = 128,
    supersample: int = 1,
) -> np.ndarray:
    """Image of a flat board seen by a distortion-free camera: a homography warp of the board image.

    The board image is ``BoardSpec.board().generateImage`` at ``pixels_per_m`` with ``margin_px``;
    a board point (X, Y, 0) (metres) lies at board pixel ``margin + p X - 0.5`` (pixel-centre
    convention). The camera sees it at ``K [r1 r2 t] (X, Y, 1)``, so the warp is
    ``H = K [r1 r2 t] A^-1`` with A the board-pixel map. ``supersample`` renders at that factor
    and averages pixel blocks down, as a sensor integrates light over each pixel (less aliasing
    than sampling the board once per pixel). Used to synthesise calibration data.
    """
    R, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    Rt = np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, np.float64).reshape(3)])
    A = np.array([[pixels_per_m, 0, margin_px - 0.5], [0, pixels_per_m, margin_px - 0.5], [0, 0, 1]])
    s = int(supersample)
    up = np.array([[s, 0, (s - 1) * 0.5], [0, s, (s - 1) * 0.5], [0, 0, 1]])  # pixel-centre convention
    H = up @ np.asarray(K, np.float64) @ Rt @ np.linalg.inv(A)
    big = cv2.warpPerspective(board_image, H, (size[0] * s, size[1] * s), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    return big if s == 1 else cv2.resize(big, size, interpolation=cv2.INTER_AREA)


def capture_views(
    grabber: PairGrabber,
    board: BoardSpec,
    n_views: int,
    *,
    save_to: str | Path | None = None,
    progress: Progress | None = None,
    min_corners: int = 12,
    min_move: float = 0.02,
    max_seconds: float = 600.0,
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Collect ``n_views`` distinct board views from a stereo grabber (a camera pair or a video).

    A pair is kept when both cameras see at least ``min_corners`` common corners and the board
    moved by more than ``min_move`` x image width (mean corner shift) from every kept view, so that
    holding the board still does not fill the set with copies. ``grabber`` is any object with
    open/grab/close (``stereo_pair.V4L2Grabber``, ``video.VideoGrabber``, ``stereo_pair.ImagePairGrabber``);
    the caller builds it, so this module does not depend on the capture code (which depends on it).
    """
    import time

    from device.errors import SourceDisconnected

    say = progress or (lambda _msg: None)
    detector = cv2.aruco.CharucoDetector(board.board())
    kept: list[tuple[str, np.ndarray, np.ndarray]] = []
    kept_corners: list[dict[int, np.ndarray]] = []
    out_dir = Path(save_to) if save_to else None
    if out_dir:
        (out_dir / "left").mkdir(parents=True, exist_ok=True)
        (out_dir / "right").mkdir(parents=True, exist_ok=True)
    grabber.open()
    deadline = time.monotonic() + max_seconds
    try:
        say(f"show the {board.squares_x}x{board.squares_y} ChArUco board to both cameras; "
            f"move it between views ({n_views} needed)")
        while len(kept) < n_views:
            if time.monotonic() > deadline:
                raise CalibrationError(f"only {len(kept)} of {n_views} views collected in {max_seconds:.0f} s; "
                                       "hold the whole board in view of both cameras, in good light")
            try:
                left, right, _ = grabber.grab(1.0)
            except SourceDisconnected:
                if len(kept) >= 6:
                    break  # a finite recording ran out; calibrate with what there is
                raise
            dl, dr = detect_board(detector, left), detect_board(detector, right)
            if dl is None or dr is None:
                continue
            common = np.intersect1d(dl.ids, dr.ids)
            if len(common) < min_corners:
                continue
            here = {int(i): c for i, c in zip(dl.ids, dl.corners)}
            width = left.shape[1]
            moved = True
            for prev in kept_corners:
                shared = [i for i in here if i in prev]
                if shared and np.mean([np.linalg.norm(here[i] - prev[i]) for i in shared]) < min_move * width:
                    moved = False
                    break
            if not moved:
                continue
            name = f"view{len(kept):03d}"
            kept.append((name, left.copy(), right.copy()))
            kept_corners.append(here)
            if out_dir:
                cv2.imwrite(str(out_dir / "left" / f"{name}.png"), left)
                cv2.imwrite(str(out_dir / "right" / f"{name}.png"), right)
            say(f"view {len(kept)}/{n_views}: {len(common)} corners")
    finally:
        grabber.close()
    return kept
