"""Stereo calibration on ChArUco views rendered through two virtual cameras with known geometry."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from device.calibration.board import BoardSpec, render_board_view
from device.calibration.capture import capture_views
from device.calibration.solve import calibrate_stereo, load_image_pairs
from device.calibration.stereo import FORMAT, calibration_from_json, load_calibration
from device.errors import CalibrationError
from device.sources.stereo_pair import ImagePairGrabber
from cli.main import app

SIZE = (1280, 720)
K_LEFT = np.array([[1000.0, 0, 640.5], [0, 1002.0, 359.5], [0, 0, 1]])
K_RIGHT = np.array([[995.0, 0, 630.25], [0, 997.0, 362.75], [0, 0, 1]])
R_LR, _ = cv2.Rodrigues(np.array([0.002, -0.015, 0.004]))
T_LR = np.array([-0.06, 0.0004, 0.0008])  # metres: X_right = R X_left + T
BOARD = BoardSpec()
PX_PER_M, MARGIN = 4000.0, 40
SUPERSAMPLE = 2


def _board_image(board: BoardSpec = BOARD) -> np.ndarray:
    w = round(board.squares_x * board.square_m * PX_PER_M) + 2 * MARGIN
    h = round(board.squares_y * board.square_m * PX_PER_M) + 2 * MARGIN
    return board.board().generateImage((w, h), marginSize=MARGIN, borderBits=1)


def _render_views(n: int, seed: int = 1, board: BoardSpec = BOARD) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """n view pairs of the board at random poses 0.45-0.8 m away, tilted up to ~26 degrees."""
    img = _board_image(board)
    rng = np.random.default_rng(seed)
    centre = np.array([BOARD.squares_x * BOARD.square_m / 2, BOARD.squares_y * BOARD.square_m / 2, 0])
    views = []
    for k in range(n):
        angles = np.r_[rng.uniform(-0.45, 0.45, 2), rng.uniform(-0.3, 0.3)]
        R, _ = cv2.Rodrigues(angles)
        t = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0.45, 0.8)]) - R @ centre
        r_right, _ = cv2.Rodrigues(R_LR @ R)
        left = render_board_view(img, PX_PER_M, MARGIN, K_LEFT, angles, t, SIZE, supersample=SUPERSAMPLE)
        right = render_board_view(img, PX_PER_M, MARGIN, K_RIGHT, r_right.ravel(), R_LR @ t + T_LR, SIZE,
                                  supersample=SUPERSAMPLE)
        views.append((f"v{k:02d}", left, right))
    return views


@pytest.fixture(scope="module")
def views():
    return _render_views(15)


def _check_recovered(calib) -> None:
    assert calib.K1[0, 0] == pytest.approx(K_LEFT[0, 0], rel=0.005)
    assert calib.K1[1, 1] == pytest.approx(K_LEFT[1, 1], rel=0.005)
    assert calib.K2[0, 0] == pytest.approx(K_RIGHT[0, 0], rel=0.005)
    assert calib.baseline_m == pytest.approx(np.linalg.norm(T_LR), rel=0.01)
    assert np.allclose(calib.T, T_LR, atol=0.001)
    rot_err = np.linalg.norm(cv2.Rodrigues(calib.R @ R_LR.T)[0])
    assert rot_err < np.deg2rad(0.2)


@pytest.mark.slow
def test_synthetic_stereo_calibration_recovers_rig(views, capsys):
    lines = []
    calib = calibrate_stereo(views, BOARD, progress=lines.append)
    _check_recovered(calib)
    assert calib.rms < 0.5 and calib.rms_left < 0.5 and calib.rms_right < 0.5
    assert all(v.used for v in calib.views) and len(calib.views) == 15
    assert all(0 < v.error_left < 1.0 and 0 < v.error_stereo < 1.0 for v in calib.views)
    assert any("[15/15]" in line for line in lines) and "baseline" in lines[-1]
    with capsys.disabled():
        print(f"\n  synthetic calibration: fx {calib.K1[0, 0]:.2f} (true 1000), "
              f"fx_r {calib.K2[0, 0]:.2f} (true 995), baseline {calib.baseline_m * 1000:.3f} mm (true "
              f"{np.linalg.norm(T_LR) * 1000:.3f}), RMS {calib.rms:.3f} px (L {calib.rms_left:.3f}, "
              f"R {calib.rms_right:.3f})")


@pytest.mark.slow
def test_bad_views_rejected(views):
    blank = np.full((SIZE[1], SIZE[0], 3), 128, np.uint8)
    # A pair captured out of sync: the right image shows the board of another moment (pose).
    other = _render_views(1, seed=99)[0]
    desync = ("desync", views[3][1], other[2])
    calib = calibrate_stereo([*views, ("blank", blank, blank), desync], BOARD)
    by_name = {v.name: v for v in calib.views}
    assert not by_name["blank"].used and "too few corners" in by_name["blank"].reason
    assert not by_name["desync"].used and "stereo error" in by_name["desync"].reason
    assert sum(v.used for v in calib.views) == 15
    _check_recovered(calib)


def test_too_few_views_says_what_to_do(views):
    blank = np.full((SIZE[1], SIZE[0], 3), 128, np.uint8)
    with pytest.raises(CalibrationError, match="only 3 usable views.*capture more pairs"):
        calibrate_stereo([*views[:3], ("blank", blank, blank)], BOARD)
    with pytest.raises(CalibrationError, match="no view pairs"):
        calibrate_stereo([], BOARD)
    small = cv2.resize(views[0][2], (640, 360))
    with pytest.raises(CalibrationError, match="one size"):
        calibrate_stereo([("v", views[0][1], small)], BOARD)
    with pytest.raises(CalibrationError, match="dictionary"):
        BoardSpec(dictionary="DICT_NOPE")
    with pytest.raises(CalibrationError, match="smaller than the square"):
        BoardSpec(square_m=0.02, marker_m=0.03)


def test_a_legacy_pattern_board_is_found_and_calibrates():
    """A board printed by OpenCV before 4.6 (11x8: an even number of rows, so the chessboard is shifted
    against today's): today's detector finds its markers but no corner. The detector retries the legacy
    pattern by itself, calibrate says to pass --legacy, and the rig is recovered as with today's board."""
    import dataclasses

    from device.calibration.board import BoardDetector, detect_board

    legacy = dataclasses.replace(BOARD, legacy=True)
    views = _render_views(8, seed=3, board=legacy)
    plain = detect_board(cv2.aruco.CharucoDetector(BOARD.board()), views[0][1])
    assert plain is None or len(plain.ids) < 6  # what made check and calibrate give up
    detector = BoardDetector(BOARD)
    found = detector.detect(views[0][1])
    assert detector.switched and detector.board == legacy and len(found.ids) >= 0.8 * BOARD.n_corners
    lines: list[str] = []
    calib = calibrate_stereo(views, BOARD, progress=lines.append)
    assert any("--legacy" in line for line in lines)
    assert calib.baseline_m == pytest.approx(np.linalg.norm(T_LR), rel=0.01) and calib.rms < 0.5
    # Told it is legacy, nothing is retried; an odd number of rows is the same board in both patterns.
    told = BoardDetector(legacy)
    assert len(told.detect(views[0][1]).ids) == len(found.ids) and not told.switched
    odd = BoardSpec(7, 5)
    assert odd.board().getChessboardCorners().tolist() == dataclasses.replace(odd, legacy=True).board().getChessboardCorners().tolist()


def test_file_round_trip_and_format(views, tmp_path):
    calib = calibrate_stereo(views[:8], BOARD)
    path = calib.save(tmp_path / "cal" / "rig.json")
    data = json.loads(path.read_text())
    assert data["format"] == FORMAT and data["version"] == 1 and data["image_size"] == list(SIZE)
    assert len(data["T"]) == 3 and data["baseline_m"] == pytest.approx(calib.baseline_m)
    assert data["board"]["square_m"] == BOARD.square_m and len(data["views"]) == 8
    back = load_calibration(path)
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        assert np.array_equal(getattr(back, name), np.asarray(getattr(calib, name)).reshape(getattr(back, name).shape))
    assert back.rms == calib.rms and back.views == calib.views and back.board == BOARD


def test_bad_calibration_files(tmp_path):
    with pytest.raises(CalibrationError, match="does not exist.*depthruler calibrate"):
        load_calibration(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        load_calibration(bad)
    k = [[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]]
    good = {"image_size": [640, 480], "K1": k, "K2": k, "D1": [0] * 5,
            "D2": [0] * 5, "R": np.eye(3).tolist(), "T": [-0.06, 0, 0]}
    assert calibration_from_json(good).baseline_m == pytest.approx(0.06)
    cases = {
        "T must be in metres": {**good, "T": [-60.0, 0, 0]},
        "'K1' must have shape": {**good, "K1": [[1, 0], [0, 1]]},
        "'R' is missing": {k: v for k, v in good.items() if k != "R"},
        "not a rotation": {**good, "R": (2 * np.eye(3)).tolist()},
        "image_size": {**good, "image_size": [640, -1]},
        "'D2' must have": {**good, "D2": [0, 0]},
        "T is zero": {**good, "T": [0, 0, 0]},
        "'board' is malformed": {**good, "board": {"squares": 3}},
        "K1: camera fx=1 px is outside the physical range": {**good, "K1": np.eye(3).tolist()},
        "version 'one' must be a whole number": {**good, "version": "one"},
        "'rms' must be a number": {**good, "rms": [0.3]},
        "R is not a rotation": {**good, "R": np.diag([1.0, 1.0, -1.0]).tolist()},
    }
    for message, data in cases.items():
        with pytest.raises(CalibrationError, match=message):
            calibration_from_json(data)


@pytest.mark.slow
def test_folder_layouts_and_cli(views, tmp_path):
    (tmp_path / "lr" / "left").mkdir(parents=True)
    (tmp_path / "lr" / "right").mkdir()
    (tmp_path / "sbs").mkdir()
    (tmp_path / "named").mkdir()
    for name, left, right in views[:8]:
        cv2.imwrite(str(tmp_path / "lr" / "left" / f"{name}.png"), left)
        cv2.imwrite(str(tmp_path / "lr" / "right" / f"{name}.png"), right)
        cv2.imwrite(str(tmp_path / "sbs" / f"{name}.png"), np.hstack([left, right]))
        cv2.imwrite(str(tmp_path / "named" / f"{name}_left.png"), left)
        cv2.imwrite(str(tmp_path / "named" / f"{name}_right.png"), right)
    for folder, sbs in (("lr", False), ("sbs", True), ("named", False)):
        pairs = load_image_pairs(tmp_path / folder, side_by_side=sbs)
        assert [p[0] for p in pairs] == [v[0] for v in views[:8]]
        assert np.array_equal(pairs[2][2][:, :, 0], views[2][2])  # written grey, read back as BGR
    with pytest.raises(CalibrationError, match="no left/right image pairs"):
        load_image_pairs(tmp_path / "sbs")
    with pytest.raises(CalibrationError, match="does not exist"):
        load_image_pairs(tmp_path / "missing")

    out = tmp_path / "rig.json"
    result = CliRunner().invoke(app, ["calibrate", "--images", str(tmp_path / "lr"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "[8/8]" in result.output and "RMS" in result.output and f"wrote {out}" in result.output
    assert load_calibration(out).baseline_m == pytest.approx(np.linalg.norm(T_LR), rel=0.01)
    # The same calibration as ROS camera_info files, read back through the source-spec path.
    from device.calibration.files import load_any

    result = CliRunner().invoke(app, ["calibrate", "--images", str(tmp_path / "lr"), "--out", str(tmp_path / "rig.yaml"),
                                      "--format", "ros"])
    assert result.exit_code == 0, result.output
    ros = load_any(f"{tmp_path / 'rig_left.yaml'},{tmp_path / 'rig_right.yaml'}")
    assert np.allclose(ros.T, load_calibration(out).T, atol=1e-9) and np.allclose(ros.R, load_calibration(out).R, atol=1e-9)
    result = CliRunner().invoke(app, ["calibrate", "--images", str(tmp_path / "lr"), "--format", "matlab"])
    assert result.exit_code == 2 and "opencv-yaml" in result.output
    result = CliRunner().invoke(app, ["calibrate", "--images", str(tmp_path / "named" / "nope"), "--out", str(out)])
    assert result.exit_code == 1 and "does not exist" in result.output
    result = CliRunner().invoke(app, ["calibrate", "--out", str(out)])
    assert result.exit_code == 2 and "exactly one of --images DIR or --live SPEC" in result.output
    result = CliRunner().invoke(app, ["calibrate", "--live", "oak", "--out", str(out)])
    assert result.exit_code == 1 and "v4l2: or video:" in result.output
    result = CliRunner().invoke(app, ["calibrate", "--live", "v4l2:/dev/video99", "--out", str(out)])
    assert result.exit_code == 1 and "no V4L2 device /dev/video99" in result.output


@pytest.mark.slow
def test_live_capture_keeps_distinct_views(views):
    # A person holding the board still for a while: repeated pairs must not count as new views.
    stream = [(v[1], v[2]) for v in views[:7] for _ in range(3)]
    lines = []
    kept = capture_views(ImagePairGrabber(stream), BOARD, 7, progress=lines.append)
    assert len(kept) == 7
    assert [np.array_equal(k[1], v[1]) for k, v in zip(kept, views[:7])] == [True] * 7
    assert lines[-1].startswith("view 7/7")


@pytest.mark.slow
def test_calibration_rectifies_and_measures_the_board(views):
    """End to end: calibrate, rectify a view with the stereo-pair code, triangulate board corners.

    Rows must align (epipolar lines horizontal) and the 3D distance between far-apart corners,
    from disparity alone, must match the printed board.
    """
    from device.sources.stereo_processing import StereoProcessor

    calib = calibrate_stereo(views, BOARD)
    proc = StereoProcessor(calib)
    detector = cv2.aruco.CharucoDetector(BOARD.board())
    corners3d = BOARD.board().getChessboardCorners()
    for _name, left, right in _render_views(3, seed=7):  # views not used for calibration
        left_r, right_r, rect = proc.rectify(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR),
                                             cv2.cvtColor(right, cv2.COLOR_GRAY2BGR))
        cl, il, _, _ = detector.detectBoard(cv2.cvtColor(left_r, cv2.COLOR_BGR2GRAY))
        cr, ir, _, _ = detector.detectBoard(cv2.cvtColor(right_r, cv2.COLOR_BGR2GRAY))
        common, a, b = np.intersect1d(il.ravel(), ir.ravel(), return_indices=True)
        pl, pr = cl.reshape(-1, 2)[a], cr.reshape(-1, 2)[b]
        assert np.median(np.abs(pl[:, 1] - pr[:, 1])) < 0.3  # rectified: same row in both images
        cam = rect.camera
        z = cam.fx * rect.baseline_m / (pl[:, 0] - pr[:, 0] + rect.doffs)
        pts = np.column_stack([(pl[:, 0] - cam.cx) * z / cam.fx, (pl[:, 1] - cam.cy) * z / cam.fy, z])
        i, j = int(np.argmin(common)), int(np.argmax(common))
        measured = np.linalg.norm(pts[i] - pts[j])
        true = np.linalg.norm(corners3d[common[i]] - corners3d[common[j]])
        assert measured == pytest.approx(true, rel=0.01)
