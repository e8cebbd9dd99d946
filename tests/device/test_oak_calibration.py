"""OAK calibration read without a device: intrinsics at an output size and the calibrated baseline from
host-built dai.CalibrationHandler objects."""

from __future__ import annotations

import numpy as np
import pytest

from device.errors import CalibrationError
from device.sources.oak import baseline_m_from_calibration, intrinsics_from_calibration

import depthai as dai  # noqa: E402  (device.sources.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)

from oak_helpers import FIXTURE, A, B, C, fixture_camera  # noqa: E402


def test_intrinsics_scale_from_json_fixture():
    calib = dai.CalibrationHandler(str(FIXTURE))
    raw = np.asarray(fixture_camera(0)["intrinsicMatrix"])
    cam_w, cam_h = fixture_camera(0)["width"], fixture_camera(0)["height"]
    assert (cam_w, cam_h) == (1920, 1080)
    cam = intrinsics_from_calibration(calib, 1280, 720)
    s = 1280 / 1920
    assert cam.fx == pytest.approx(raw[0, 0] * s, rel=1e-6)
    assert cam.fy == pytest.approx(raw[1, 1] * s, rel=1e-6)
    assert cam.cx == pytest.approx(raw[0, 2] * s, abs=1e-3)
    assert cam.cy == pytest.approx(raw[1, 2] * s, abs=1e-3)
    assert (cam.width, cam.height) == (1280, 720)
    full = intrinsics_from_calibration(calib, 1920, 1080)
    assert full.fx == pytest.approx(raw[0, 0], rel=1e-6)


def test_baseline_is_calibrated_and_in_metres():
    calib = dai.CalibrationHandler(str(FIXTURE))
    t = fixture_camera(1)["extrinsics"]["translation"]  # CAM_B -> CAM_C, centimetres
    expected_m = float(np.linalg.norm([t["x"], t["y"], t["z"]])) / 100.0
    assert baseline_m_from_calibration(calib) == pytest.approx(expected_m, rel=1e-6)
    assert expected_m == pytest.approx(0.074812, abs=1e-5)  # not the 7.5 cm board-design value

    # Filled in memory: a 12 cm calibrated baseline on a board designed for 7.5 cm.
    mem = dai.CalibrationHandler()
    mem.setCameraIntrinsics(A, [[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]], 1280, 720)
    mem.setCameraIntrinsics(B, [[800.0, 0, 640], [0, 800.0, 400], [0, 0, 1]], 1280, 800)
    mem.setCameraIntrinsics(C, [[800.0, 0, 640], [0, 800.0, 400], [0, 0, 1]], 1280, 800)
    eye = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]
    mem.setCameraExtrinsics(B, C, eye, [-12.0, 0.0, 0.0], [-7.5, 0.0, 0.0])
    mem.setStereoLeft(B, eye)
    mem.setStereoRight(C, eye)
    assert baseline_m_from_calibration(mem) == pytest.approx(0.12, rel=1e-6)
    assert intrinsics_from_calibration(mem, 640, 360).fx == pytest.approx(500.0, rel=1e-6)


def test_missing_calibration_is_a_calibration_error():
    empty = dai.CalibrationHandler()
    with pytest.raises(CalibrationError, match="no calibration"):
        intrinsics_from_calibration(empty, 1280, 720)
    with pytest.raises(CalibrationError):
        baseline_m_from_calibration(empty)
