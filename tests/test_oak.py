"""OAK / DepthAI layer without a device: calibration handling, message conversion, config, errors."""

from __future__ import annotations

import json
import os
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest

from device import SourceDisconnected, SourceError, SourceNotFound, SourceSpec, SourceTimeout, open_source
from device.errors import CalibrationError
from device.oak import (
    PRESETS,
    OakConfig,
    baseline_m_from_calibration,
    camera_for_frame,
    config_from_spec,
    configure_stereo,
    depth_to_disparity,
    frame_from_messages,
    intrinsics_from_calibration,
    preset_mode,
    read_group,
)

import depthai as dai  # noqa: E402  (device.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)

FIXTURE = Path(__file__).parent / "fixtures" / "oak_calib.json"
A, B, C = dai.CameraBoardSocket.CAM_A, dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C


def _fixture_camera(socket: int) -> dict:
    data = json.loads(FIXTURE.read_text())
    return next(cam for sock, cam in data["cameraData"] if sock == socket)


def _img(arr: np.ndarray, kind) -> dai.ImgFrame:
    f = dai.ImgFrame()
    f.setCvFrame(arr, kind)
    return f


def test_open_without_device_raises_not_found_fast():
    if dai.Device.getAllAvailableDevices():
        pytest.skip("an OAK is attached")
    # The search bound that makes "no device" fail fast instead of DepthAI's 11 s default.
    assert OakConfig().search_timeout_ms <= 3000
    assert int(os.environ["DEPTHAI_SEARCH_TIMEOUT"]) <= 3000
    with pytest.raises(SourceNotFound) as err:
        open_source("oak")
    msg = str(err.value)
    assert "plug" in msg and "--source sim" in msg
    with pytest.raises(SourceNotFound, match="1844301011B546F500"):
        open_source("oak:1844301011B546F500?search_timeout_ms=300")


def test_busy_and_wrong_devices_named(monkeypatch):
    from device.oak import find_device

    def info(mxid, state):
        i = dai.DeviceInfo(mxid)
        i.state = state
        return i

    other = info("14442C10D13EABCE00", dai.XLinkDeviceState.X_LINK_UNBOOTED)
    busy = info("1844301011B546F500", dai.XLinkDeviceState.X_LINK_BOOTED)
    monkeypatch.setattr(dai.Device, "getAllAvailableDevices", staticmethod(lambda: [other]))
    monkeypatch.setattr(dai.Device, "getAllConnectedDevices", staticmethod(lambda: [other, busy]))
    assert find_device("", 100).getDeviceId() == "14442C10D13EABCE00"
    with pytest.raises(SourceNotFound, match="1844301011B546F500 is connected but in use"):
        find_device("1844301011B546F500", 100)
    with pytest.raises(SourceNotFound, match="attached: 14442C10D13EABCE00"):
        find_device("19443010A1C2D3E4F5", 100)


def test_spec_parsing_and_bad_options():
    cfg = config_from_spec(SourceSpec.parse("oak:1844301011B546F500?preset=high_detail&fps=10&size=640x400"
                                            "&confidence_threshold=200&lr_check=0&extended_disparity=1"))
    assert (cfg.mxid, cfg.preset, cfg.fps, cfg.size) == ("1844301011B546F500", "HIGH_DETAIL", 10.0, (640, 400))
    assert (cfg.confidence_threshold, cfg.lr_check, cfg.extended_disparity) == (200, False, True)
    assert config_from_spec(SourceSpec.parse("oak")) == OakConfig()
    with pytest.raises(SourceError, match="FAST_ACCURACY"):
        config_from_spec(SourceSpec.parse("oak?preset=turbo"))
    with pytest.raises(SourceError, match="unknown OAK option 'colour'"):
        config_from_spec(SourceSpec.parse("oak?colour=1"))
    with pytest.raises(SourceError, match="fps"):
        config_from_spec(SourceSpec.parse("oak?fps=abc"))
    with pytest.raises(SourceError, match="0..255"):
        OakConfig(confidence_threshold=300)


def test_every_preset_maps_to_its_depthai_enum():
    modes = {name: preset_mode(name) for name in PRESETS}
    assert {m.name for m in modes.values()} == set(PRESETS)
    assert len({int(m.value) for m in modes.values()}) == len(PRESETS)
    assert set(dai.node.StereoDepth.PresetMode.__members__) == set(PRESETS)


def test_stereo_config_applied_to_depthai_config_object():
    sdc = configure_stereo(dai.StereoDepthConfig(), OakConfig(subpixel=True, lr_check=False,
                                                              extended_disparity=True, confidence_threshold=180))
    assert sdc.getSubpixel() is True and sdc.getLeftRightCheck() is False and sdc.getExtendedDisparity() is True
    assert sdc.getConfidenceThreshold() == 180
    assert sdc.getDepthUnit() == dai.LengthUnit.MILLIMETER


def test_intrinsics_scale_from_json_fixture():
    calib = dai.CalibrationHandler(str(FIXTURE))
    raw = np.asarray(_fixture_camera(0)["intrinsicMatrix"])
    cam_w, cam_h = _fixture_camera(0)["width"], _fixture_camera(0)["height"]
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
    t = _fixture_camera(1)["extrinsics"]["translation"]  # CAM_B -> CAM_C, centimetres
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


def test_depth_frames_convert_to_disparity_at_colour_focal_length():
    calib = dai.CalibrationHandler(str(FIXTURE))
    w, h = 128, 72
    cam = intrinsics_from_calibration(calib, w, h)
    baseline = baseline_m_from_calibration(calib)
    rng = np.random.default_rng(0)
    depth_mm = rng.integers(300, 9000, size=(h // 2, w // 2)).astype(np.uint16)  # half size: resized
    depth_mm[:3, :] = 0  # DepthAI's "no data"
    colour = rng.integers(0, 255, size=(h, w, 3)).astype(np.uint8)
    conf_map = rng.integers(0, 255, size=(h // 2, w // 2)).astype(np.uint8)
    rgb = _img(colour, dai.ImgFrame.Type.BGR888i)
    rgb.setTimestamp(timedelta(seconds=12.5))
    rgb.setSequenceNum(7)
    frame = frame_from_messages(rgb, _img(depth_mm, dai.ImgFrame.Type.RAW16), _img(conf_map, dai.ImgFrame.Type.RAW8),
                                cam, baseline)
    assert frame.image.shape == (h, w, 3) and np.array_equal(frame.image, colour)
    up = np.repeat(np.repeat(depth_mm, 2, axis=0), 2, axis=1)  # nearest-neighbour upsampling
    valid = up > 0
    expected = cam.fx * baseline / (up[valid] / 1000.0)
    assert np.allclose(frame.disparity[valid], expected, rtol=1e-5)
    assert np.isnan(frame.disparity[~valid]).all()
    assert np.allclose(frame.depth()[valid], up[valid] / 1000.0, rtol=1e-5)  # exact round trip to metres
    conf_up = np.repeat(np.repeat(conf_map, 2, axis=0), 2, axis=1)
    assert np.allclose(frame.confidence[valid], 1 - conf_up[valid] / 255.0, atol=1e-6)
    assert (frame.confidence[~valid] == 0).all()
    assert frame.timestamp == pytest.approx(12.5) and frame.meta["sequence"] == 7
    assert frame.camera == cam and frame.baseline_m == baseline and frame.doffs == 0.0


def test_depth_to_disparity_known_values():
    d = depth_to_disparity(np.array([[0, 1000, 2000, 500]], np.uint16), fx=800.0, baseline_m=0.075)
    assert np.isnan(d[0, 0])
    assert d[0, 1:] == pytest.approx([60.0, 30.0, 120.0])
    assert d.dtype == np.float32


def test_frame_transformation_wins_over_calibration():
    calib = dai.CalibrationHandler(str(FIXTURE))
    fallback = intrinsics_from_calibration(calib, 128, 72)
    rgb = _img(np.zeros((72, 128, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    assert camera_for_frame(rgb, fallback) == fallback
    t = dai.ImgTransformation(256, 144, [[200.0, 0, 128.0], [0, 202.0, 72.0], [0, 0, 1]])
    t.addScale(0.5, 0.5)  # what the ISP did: 256x144 -> 128x72
    rgb.setTransformation(t)
    cam = camera_for_frame(rgb, fallback)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == pytest.approx((100, 101, 64, 36, 128, 72))
    # A frame of another size than requested, without a transformation: scale the fallback.
    other = _img(np.zeros((144, 256, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    assert camera_for_frame(other, fallback).fx == pytest.approx(2 * fallback.fx)


def test_queue_failures_become_typed_errors():
    q = dai.MessageQueue("sync", 4, False)
    with pytest.raises(SourceTimeout, match="no frame"):
        read_group(q, 0.05)
    group = dai.MessageGroup()
    group["depth"] = _img(np.ones((4, 4), np.uint16), dai.ImgFrame.Type.RAW16)
    q.send(group)
    assert read_group(q, 0.5)["depth"].getWidth() == 4
    q.close()  # what a pipeline stop or a pulled cable does to the queue
    with pytest.raises(SourceDisconnected, match="USB cable"):
        read_group(q, 0.05)


def test_depth_must_be_millimetres():
    rgb = _img(np.zeros((8, 8, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    calib = dai.CalibrationHandler(str(FIXTURE))
    cam = intrinsics_from_calibration(calib, 8, 8)
    with pytest.raises(SourceError, match="uint16"):
        frame_from_messages(rgb, _img(np.zeros((8, 8), np.uint8), dai.ImgFrame.Type.RAW8), None, cam, 0.075)


@pytest.mark.hardware
def test_real_oak_delivers_registered_frames():
    with open_source("oak") as src:
        frame = src.read(timeout_s=5.0)
    assert frame.image.shape[:2] == frame.disparity.shape == (720, 1280)
    assert 0.02 < frame.baseline_m < 0.2
    assert np.isfinite(frame.disparity).mean() > 0.2
