"""Calibration people already have: OpenCV FileStorage YAML/XML, ROS camera_info pairs, units, distortion
models, the printable board; and the calibration -> capture import direction."""

from __future__ import annotations

import ast
import re
import struct
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree
from typer.testing import CliRunner

from device.calibration.board import BoardSpec, write_board_png
from device.calibration.stereo import StereoCalibration
from device.calibration.files import CalibrationRef, load_any, write
from device.errors import CalibrationError
from device.sources.stereo_processing import rectification

SIZE = (640, 480)
K1 = np.array([[520.25, 0, 321.75], [0, 519.5, 242.125], [0, 0, 1]])
K2 = np.array([[517.0, 0, 316.5], [0, 516.25, 238.0], [0, 0, 1]])
R, _ = cv2.Rodrigues(np.array([0.004, -0.012, 0.003]))
T = np.array([-0.0625, 0.0006, -0.0011])  # metres, X_right = R X_left + T
D_PINHOLE = np.array([-0.28, 0.09, 0.0007, -0.0004, -0.012])
D_FISHEYE = np.array([-0.012, 0.031, -0.019, 0.004])


def _calib(model: str = "opencv") -> StereoCalibration:
    d = D_FISHEYE if model == "equidistant" else D_PINHOLE
    return StereoCalibration(image_size=SIZE, K1=K1, D1=d, K2=K2, D2=d * 0.9, R=R, T=T, distortion_model=model)


def _storage(path: Path, nodes: dict) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in nodes.items():
        fs.write(k, v)
    fs.release()
    return path


def test_opencv_sample_files_intrinsics_and_extrinsics_in_mm(tmp_path):
    """As OpenCV's stereo_calib sample writes them (two files, M1/D1/M2/D2 and R/T/R1/..), T in mm."""
    intr = _storage(tmp_path / "intrinsics.yml", {"M1": K1, "D1": D_PINHOLE.reshape(1, 5), "M2": K2,
                                                  "D2": D_PINHOLE.reshape(1, 5), "image_width": 640, "image_height": 480})
    extr = _storage(tmp_path / "extrinsics.yml", {"R": R, "T": (T * 1000).reshape(3, 1), "R1": np.eye(3),
                                                  "P1": np.zeros((3, 4))})
    ref = f"{intr},{extr}"
    with pytest.raises(CalibrationError, match="calib_units=mm"):
        load_any(ref)  # 62.5 "m": refused, and told what to add
    c = CalibrationRef(ref, units="mm").load()
    assert np.array_equal(c.K1, K1) and np.array_equal(c.K2, K2) and np.array_equal(c.R, R)
    assert c.T == pytest.approx(T, abs=1e-15) and c.image_size == SIZE and c.distortion_model == "opencv"
    # The sample does not write the image size: say which keys to add.
    no_size = _storage(tmp_path / "nosize.yml", {"M1": K1, "D1": D_PINHOLE, "M2": K2, "D2": D_PINHOLE})
    with pytest.raises(CalibrationError, match="image_width and image_height"):
        load_any(f"{no_size},{extr}", units="mm")
    with pytest.raises(CalibrationError, match="calib_units='ft' must be one of m, cm, mm, in, squares"):
        CalibrationRef(ref, units="ft")


@pytest.mark.parametrize("fmt,suffix", [("opencv-yaml", ".yaml"), ("opencv-xml", ".xml")])
def test_opencv_round_trip_is_exact(tmp_path, fmt, suffix):
    for model in ("opencv", "equidistant"):
        calib = _calib(model)
        (path,) = write(calib, tmp_path / f"rig_{model}", fmt)
        assert path.suffix == suffix
        back = load_any(str(path))
        for name in ("K1", "D1", "K2", "D2", "R", "T"):
            assert np.array_equal(np.asarray(getattr(back, name)).ravel(), np.asarray(getattr(calib, name)).ravel()), name
        assert back.image_size == SIZE and back.distortion_model == model


@pytest.mark.parametrize("model", ["opencv", "equidistant"])
def test_ros_camera_info_pair_round_trip(tmp_path, model):
    """ROS stores the extrinsics through the rectification (R_rect, P); reading must recover R and T."""
    calib = _calib(model)
    left, right = write(calib, tmp_path / "rig.yaml", "ros")
    assert (left.name, right.name) == ("rig_left.yaml", "rig_right.yaml")
    text = left.read_text()
    assert f"distortion_model: {'equidistant' if model == 'equidistant' else 'plumb_bob'}" in text
    back = CalibrationRef(f"{left},{right}").load()
    assert np.allclose(back.R, R, atol=1e-12) and np.allclose(back.T, T, atol=1e-12)
    assert np.array_equal(back.K1, K1) and np.array_equal(back.D2, calib.D2) and back.distortion_model == model
    with pytest.raises(CalibrationError, match="both cameras"):
        load_any(str(left))


def test_distortion_model_is_explicit(tmp_path):
    four = _storage(tmp_path / "four.yaml", {"K1": K1, "D1": D_FISHEYE, "K2": K2, "D2": D_FISHEYE, "R": R, "T": T,
                                             "image_size": np.array([640, 480])})
    with pytest.raises(CalibrationError, match="ambiguous.*distortion=opencv\\|equidistant"):
        load_any(str(four))
    assert load_any(str(four), distortion_model="equidistant").distortion_model == "equidistant"
    assert load_any(str(four), distortion_model="opencv").distortion_model == "opencv"
    with pytest.raises(CalibrationError, match="unknown"):
        load_any(str(four), distortion_model="kannala")
    five = _storage(tmp_path / "five.yaml", {"K1": K1, "D1": D_PINHOLE, "K2": K2, "D2": D_PINHOLE, "R": R, "T": T,
                                             "image_size": np.array([640, 480])})
    with pytest.raises(CalibrationError, match="must have 4 numbers"):
        load_any(str(five), distortion_model="equidistant")


@pytest.mark.parametrize("model", ["opencv", "equidistant"])
def test_rectification_of_both_models_puts_points_on_one_row_at_true_depth(model):
    """3D points projected into the raw (distorted) images land, through our rectification maps, on the
    same row in both rectified images, with the disparity of their depth."""
    calib = _calib(model)
    rect = rectification(calib, SIZE)
    rng = np.random.default_rng(3)
    z = rng.uniform(0.8, 3.0, 60)
    xn, yn = rng.uniform(-0.35, 0.35, 60), rng.uniform(-0.25, 0.25, 60)
    pts = np.column_stack([xn * z, yn * z, z])
    rvec_r = cv2.Rodrigues(R)[0]
    if model == "equidistant":
        pl = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K1, calib.D1)[0]
        pr = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), rvec_r, T, K2, calib.D2)[0]
    else:
        pl = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K1, calib.D1)[0]
        pr = cv2.projectPoints(pts, rvec_r, T, K2, calib.D2)[0]
    pl, pr = pl.reshape(-1, 2), pr.reshape(-1, 2)
    inside = (pl.min(1) > 5) & (pl[:, 0] < SIZE[0] - 5) & (pl[:, 1] < SIZE[1] - 5)
    inside &= (pr.min(1) > 5) & (pr[:, 0] < SIZE[0] - 5) & (pr[:, 1] < SIZE[1] - 5)

    def rectified(mx, my, raw):
        # The maps give each rectified pixel's raw position; invert by nearest neighbour + local affine fit.
        tree = cKDTree(np.column_stack([mx.ravel(), my.ravel()]))
        _, idx = tree.query(raw, k=9)
        ys, xs = np.unravel_index(idx, mx.shape)
        out = []
        for k in range(len(raw)):
            src = np.column_stack([mx[ys[k], xs[k]], my[ys[k], xs[k]], np.ones(9)])
            coef, *_ = np.linalg.lstsq(src, np.column_stack([xs[k], ys[k]]), rcond=None)
            out.append(np.r_[raw[k], 1.0] @ coef)
        return np.asarray(out)

    ql = rectified(rect.maps[0], rect.maps[1], pl[inside])
    qr = rectified(rect.maps[2], rect.maps[3], pr[inside])
    assert inside.sum() > 30
    assert np.max(np.abs(ql[:, 1] - qr[:, 1])) < 0.05  # same row
    # Depth along the rectified left camera's axis: rotate the points by R1 = (its rotation from the left camera).
    z_rect = rect.camera.fx * rect.baseline_m / (ql[:, 0] - qr[:, 0] + rect.doffs)
    x_rect = (ql[:, 0] - rect.camera.cx) * z_rect / rect.camera.fx
    y_rect = (ql[:, 1] - rect.camera.cy) * z_rect / rect.camera.fy
    assert np.linalg.norm(np.column_stack([x_rect, y_rect, z_rect]), axis=1) == pytest.approx(
        np.linalg.norm(pts[inside], axis=1), rel=2e-3)  # the rectified left camera sits where the left one does
    assert rect.baseline_m == pytest.approx(np.linalg.norm(T), rel=1e-9)


def _png_ppm(path: Path) -> int:
    data = path.read_bytes()
    i = data.index(b"pHYs")
    ppx, ppy, unit = struct.unpack(">IIB", data[i + 4:i + 13])
    assert ppx == ppy and unit == 1
    return ppx


def test_board_png_prints_at_its_size_and_is_detectable(tmp_path):
    from cli.main import app

    board = BoardSpec()
    out = tmp_path / "board.png"
    result = CliRunner().invoke(app, ["calibrate", "--board-png", str(out), "--dpi", "200"])
    assert result.exit_code == 0, result.output
    assert "11x8 squares of 30 mm" in result.output
    sheet = re.search(r"sheet ([0-9.]+) x ([0-9.]+) mm", result.output)
    assert (float(sheet[1]), float(sheet[2])) == pytest.approx((350.0, 260.0), abs=0.2)
    image = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    ppm = _png_ppm(out)
    assert image.shape[1] / ppm * 1000 == pytest.approx(350.0, abs=0.2)  # 330 mm of squares + 2 x 10 mm margin
    assert image.shape[0] / ppm * 1000 == pytest.approx(260.0, abs=0.2)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board.board()).detectBoard(image)
    assert ids is not None and len(ids) == board.n_corners
    # Two detected corners 10 squares apart lie 10 x 30 mm apart on the printed sheet.
    pos = dict(zip(ids.ravel().tolist(), corners.reshape(-1, 2)))
    assert np.linalg.norm(pos[9] - pos[0]) / ppm * 1000 == pytest.approx(270.0, abs=0.15)  # 9 squares along x
    path, w_mm, h_mm = write_board_png(BoardSpec(5, 4, 0.04, 0.03), tmp_path / "small.png", dpi=300, margin_mm=5)
    assert (w_mm, h_mm) == pytest.approx((210.0, 170.0), abs=0.1)


def test_calibration_does_not_import_the_capture_code():
    """The dependency runs one way: capture (stereo_pair, stereo_processing, video) -> calibration, never back."""
    root = Path(__file__).resolve().parents[2] / "device" / "calibration"
    for module in sorted(p.name for p in root.glob("*.py")):
        tree = ast.parse((root / module).read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
        imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        assert not {m for m in imported if m.split(".")[-1] in ("stereo_pair", "stereo_processing", "video", "oak")}, (module, imported)


def _sample_extrinsics(path: Path, T_written: np.ndarray, R_written: np.ndarray = R) -> Path:
    """An extrinsics file as OpenCV's stereo_calib.cpp writes it (R, T, R1, R2, P1, P2, Q), no units."""
    return _storage(path, {"R": R_written, "T": T_written.reshape(3, 1), "R1": np.eye(3), "R2": np.eye(3),
                           "P1": np.zeros((3, 4)), "P2": np.zeros((3, 4)), "Q": np.zeros((4, 4))})


def test_T_in_board_squares_as_the_opencv_sample_writes_it_is_refused_naming_the_unit(tmp_path):
    """stereo_calib.cpp's default square size is 1.0: a 62.5 mm pair calibrated on 25 mm squares writes
    |T| = 2.5 (squares). Read as metres that is a 2.5 m baseline and every length 40x too long."""
    intr = _storage(tmp_path / "intrinsics.yml", {"M1": K1, "D1": D_PINHOLE.reshape(1, 5), "M2": K2,
                                                  "D2": D_PINHOLE.reshape(1, 5), "image_width": 640, "image_height": 480})
    extr = _sample_extrinsics(tmp_path / "extrinsics.yml", T / 0.025)
    ref = f"{intr},{extr}"
    with pytest.raises(CalibrationError) as err:
        load_any(ref)
    msg = str(err.value)
    assert "calib_units=" in msg and "squares" in msg and "calib_square_mm" in msg and "2.5 m" in msg
    c = CalibrationRef(ref, units="squares", square_mm=25.0).load()
    assert c.baseline_m == pytest.approx(float(np.linalg.norm(T)), rel=1e-12)
    with pytest.raises(CalibrationError, match="calib_square_mm"):
        load_any(ref, units="squares")  # squares without the side
    # The same file with T in inches (2.46 in) or cm (6.25): refused, and the message names that unit.
    for unit, scale in (("in", 0.0254), ("cm", 0.01)):
        other = _sample_extrinsics(tmp_path / f"extrinsics_{unit}.yml", T / scale)
        with pytest.raises(CalibrationError, match=rf"likely unit is [^:]*\b{unit}\b"):
            load_any(f"{intr},{other}")
        assert load_any(f"{intr},{other}", units=unit).baseline_m == pytest.approx(float(np.linalg.norm(T)), rel=1e-12)
    # In metres inside 1 cm - 0.5 m: read silently; a file that says its units is believed.
    assert load_any(f"{intr},{_sample_extrinsics(tmp_path / 'm.yml', T)}").baseline_m == pytest.approx(0.0625, abs=1e-4)
    said = _storage(tmp_path / "said.yml", {"R": R, "T": (T * 1000).reshape(3, 1), "units": "mm"})
    assert load_any(f"{intr},{said}").baseline_m == pytest.approx(0.0625, abs=1e-4)


def test_rotations_printed_with_five_decimals_load_as_the_nearest_rotation(tmp_path):
    """2,000 small rotations (up to 3 degrees, as between two cameras of a stereo pair) written with 5
    decimals: every one loads, as a rotation (orthonormal to 1e-12, det +1) within 1e-5 of the file."""
    from device.calibration.stereo import CalibrationWarning, calibration_from_json

    rng = np.random.default_rng(8)
    data = _calib().to_json()
    for i in range(2000):
        Ri, _ = cv2.Rodrigues(rng.uniform(-1, 1, 3) * np.deg2rad(3.0) / np.sqrt(3))
        data["R"] = np.round(Ri, 5).tolist()
        with warnings.catch_warnings():
            warnings.simplefilter("error", CalibrationWarning)  # rounding alone must not warn
            c = calibration_from_json(data, source=f"rotation {i}")
        assert np.allclose(c.R @ c.R.T, np.eye(3), atol=1e-12) and np.linalg.det(c.R) == pytest.approx(1.0, abs=1e-12)
        assert np.abs(c.R - np.round(Ri, 5)).max() <= 1e-5
    # A rotation off by 1e-3 loads with a warning; a mirror or a matrix far from any rotation is refused.
    data["R"] = (np.asarray(data["R"]) + np.diag([1e-3, 0, 0])).tolist()
    with pytest.warns(CalibrationWarning, match="nearest rotation"):
        calibration_from_json(data)
    for bad, match in ((np.diag([1.0, 1.0, -1.0]), "determinant"), (np.eye(3) * 1.1, "off the nearest rotation")):
        data["R"] = bad.tolist()
        with pytest.raises(CalibrationError, match=match):
            calibration_from_json(data)
    # A file written with all its digits reads back bit for bit.
    (path,) = write(_calib(), tmp_path / "exact", "opencv-yaml")
    assert np.array_equal(load_any(str(path)).R, R)
