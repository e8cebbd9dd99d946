"""Stereo calibration of a two-camera rig with a ChArUco board, from view pairs in memory or a folder.

Procedure (OpenCV 5 API):
1. detect the board in every view pair (``CharucoDetector.detectBoard``) and keep the corners
   seen by both cameras;
2. calibrate each camera alone (``calibrateCamera`` on those matched points), compute each
   view's reprojection error and reject views worse than ``reject_factor`` x the median (a blurred
   or mis-detected view) or with too few corners, then recalibrate;
3. ``stereoCalibrate`` with the intrinsics fixed (OpenCV 5's default ``CALIB_FIX_INTRINSIC``),
   reject views whose stereo error is an outlier the same way (e.g. a pair captured out of sync)
   and solve again.

The result is a :class:`device.calibration.stereo.StereoCalibration` (errors in pixels, ``T`` in metres).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

from device.calibration.board import BoardDetector, BoardSpec
from device.calibration.stereo import StereoCalibration, ViewResult
from device.errors import CalibrationError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

Progress = Callable[[str], None]


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
    detector = BoardDetector(board)  # finds out a legacy-pattern board by itself
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
        dl, dr = detector.detect(left), detector.detect(right)
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
                f"{board.squares_y} squares {board.dictionary} must match the printed one (--legacy for a board "
                "printed by OpenCV before 4.6)"
            )

    need(len(names), "with the board seen by both cameras")
    if detector.switched:
        board = detector.board
        say("the board is in OpenCV's legacy pattern (printed before OpenCV 4.6): pass --legacy next time")
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
