"""OAK / DepthAI layer without a device: calibration handling, message conversion, config, errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from datetime import timedelta
from pathlib import Path
from unittest import mock

import numpy as np
import pytest

from device import SourceDisconnected, SourceError, SourceNotFound, SourceSpec, SourceTimeout, open_source
from device.errors import CalibrationError
from device.sources.oak import (
    PRESETS,
    UDEV_RULE,
    OakConfig,
    OakSource,
    Sockets,
    choose_sockets,
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

import depthai as dai  # noqa: E402  (device.sources.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "oak_calib.json"
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
    from device.sources.oak import find_device

    def info(mxid, state):
        i = dai.DeviceInfo(mxid)
        i.state = state
        return i

    other = info("14442C10D13EABCE00", dai.XLinkDeviceState.X_LINK_UNBOOTED)
    busy = info("1844301011B546F500", dai.XLinkDeviceState.X_LINK_BOOTED)
    monkeypatch.setattr(dai.Device, "getAllAvailableDevices", staticmethod(lambda: [other]))
    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices",
                        staticmethod(lambda skipInvalidDevices=True: [other, busy]))
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
    # Unset stereo options stay None: the preset decides them.
    assert (OakConfig().subpixel, OakConfig().lr_check, OakConfig().extended_disparity) == (None, None, None)
    assert OakConfig().auto_calibration == "off"
    cfg = config_from_spec(SourceSpec.parse("oak?align=LEFT&auto_calibration=on_start"))
    assert (cfg.align, cfg.auto_calibration) == ("left", "on_start")
    with pytest.raises(SourceError, match="auto_calibration"):
        config_from_spec(SourceSpec.parse("oak?auto_calibration=always"))
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


def test_unset_options_keep_what_the_preset_chose():
    """Defect 2: build(..., preset) fills the config; options the user did not set must not override it."""
    preset_like = dai.StereoDepthConfig()
    preset_like.setExtendedDisparity(True)  # e.g. what the depth-align example's preset + setting gives
    preset_like.setSubpixel(True)
    preset_like.setSubpixelFractionalBits(5)
    preset_like.setLeftRightCheck(False)
    preset_like.setConfidenceThreshold(15)
    out = configure_stereo(preset_like, OakConfig())
    assert out.getExtendedDisparity() is True and out.getSubpixel() is True and out.getLeftRightCheck() is False
    assert out.getSubpixelFractionalBits() == 5 and out.getConfidenceThreshold() == 15
    assert out.getDepthUnit() == dai.LengthUnit.MILLIMETER


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
    assert np.allclose(frame.confidence[valid], conf_up[valid] / 255.0, atol=1e-6)
    assert (frame.confidence[~valid] == 0).all()
    assert frame.timestamp == pytest.approx(12.5) and frame.meta["sequence"] == 7
    # Defect 8: the device clock (restarts at boot) is not the frame time; the host-synced one is.
    rgb.setTimestampDevice(timedelta(seconds=3.25))
    again = frame_from_messages(rgb, _img(depth_mm, dai.ImgFrame.Type.RAW16), None, cam, baseline)
    assert again.timestamp == pytest.approx(12.5)
    assert frame.camera == cam and frame.baseline_m == baseline and frame.doffs == 0.0


def test_confidence_map_is_v3_scale_255_is_best():
    """Defect 1: in v3 a confidence of 255 is the most confident pixel (v2 had it the other way round)."""
    calib = dai.CalibrationHandler(str(FIXTURE))
    cam = intrinsics_from_calibration(calib, 4, 2)
    rgb = _img(np.zeros((2, 4, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    depth = _img(np.full((2, 4), 1000, np.uint16), dai.ImgFrame.Type.RAW16)
    conf = _img(np.array([[255, 200, 55, 0], [255, 255, 0, 0]], np.uint8), dai.ImgFrame.Type.RAW8)
    frame = frame_from_messages(rgb, depth, conf, cam, 0.075)
    assert frame.confidence[0].tolist() == pytest.approx([1.0, 200 / 255, 55 / 255, 0.0])
    # The threshold keeps pixels above it: DepthAI's own default keeps 55 and more.
    assert dai.StereoDepthConfig().getConfidenceThreshold() == 55


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


def test_timeout_from_a_live_device_is_not_a_disconnect():
    """Defect 4: no frame in time from a device that is still open is a timeout (no reboot);
    the same wait on a closed device is a disconnect."""
    q = dai.MessageQueue("sync", 1, False)
    device = mock.create_autospec(dai.Device, instance=True)
    device.isClosed.return_value = False
    with pytest.raises(SourceTimeout) as err:
        read_group(q, 0.02, device)
    assert not isinstance(err.value, SourceDisconnected)
    device.isClosed.return_value = True
    with pytest.raises(SourceDisconnected, match="closed"):
        read_group(q, 0.02, device)


def test_newest_frame_wins_in_a_one_message_queue():
    """Defect 8: the queue the source reads (maxSize=1, non-blocking, see the wiring test) returns
    the newest message, not the oldest of four."""
    q = dai.MessageQueue("sync", 1, False)
    for seq in range(4):
        g = dai.MessageGroup()
        frame = _img(np.zeros((2, 2), np.uint16), dai.ImgFrame.Type.RAW16)
        frame.setSequenceNum(seq)
        g["depth"] = frame
        q.send(g)
    assert read_group(q, 0.1)["depth"].getSequenceNum() == 3


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


# --- permissions, sockets, wiring, types -------------------------------------------------------


def test_permission_denied_device_prints_the_udev_rule(monkeypatch):
    """Defect 6: a device without USB permission is named, with the rule to install, not hidden."""
    from device.sources.oak import find_device

    denied = dai.DeviceInfo("1.1")
    denied.status = dai.XLinkError_t.X_LINK_INSUFFICIENT_PERMISSIONS
    denied.state = dai.XLinkDeviceState.X_LINK_UNBOOTED
    calls = []

    def connected(skipInvalidDevices=True):
        calls.append(skipInvalidDevices)
        return [] if skipInvalidDevices else [denied]

    monkeypatch.setattr(dai.Device, "getAllAvailableDevices", staticmethod(lambda: []))
    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices", staticmethod(connected))
    with pytest.raises(SourceNotFound) as err:
        find_device("", 100)
    assert calls == [False]
    assert UDEV_RULE in str(err.value) and "udevadm" in str(err.value) and "plug an OAK" not in str(err.value)
    # XLink lists nothing at all, but pyusb sees the Movidius vendor id (what lsusb shows): the same advice.
    import device.sources.oak as oak
    from device import SourceInfo

    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices", staticmethod(lambda skipInvalidDevices=True: []))
    monkeypatch.setattr(oak, "list_usb", lambda: [SourceInfo(kind="usb", name="Luxonis OAK (Movidius)", state="unbooted",
                                                             extra={"usb_id": "03e7:2485"})])
    with pytest.raises(SourceNotFound, match="03e7:2485.*udev") as err:
        find_device("", 100)
    assert UDEV_RULE in str(err.value)
    monkeypatch.setattr(oak, "list_usb", lambda: [])
    with pytest.raises(SourceNotFound, match="plug an OAK"):
        find_device("", 100)


def _features(*cams) -> list:
    out = []
    for socket, kind, sensor in cams:
        f = dai.CameraFeatures()
        f.socket, f.supportedTypes, f.sensorName = socket, [kind], sensor
        out.append(f)
    return out


COLOR, MONO = dai.CameraSensorType.COLOR, dai.CameraSensorType.MONO
D = dai.CameraBoardSocket.CAM_D


def test_sockets_come_from_the_device_and_its_calibration():
    """Defect 7: sockets are read from the device, not assumed."""
    calib = dai.CalibrationHandler(str(FIXTURE))  # stereo left CAM_B, right CAM_C
    oak_d = _features((A, COLOR, "IMX378"), (B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(oak_d, calib) == Sockets(left=B, right=C, color=A)
    assert choose_sockets(oak_d, calib, "left") == Sockets(left=B, right=C, color=None)
    # A model without a colour camera aligns to the rectified left image.
    no_colour = _features((B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(no_colour, calib) == Sockets(left=B, right=C, color=None)
    with pytest.raises(SourceError, match="no colour camera"):
        choose_sockets(no_colour, calib, "color")
    # Without stereo extrinsics: the two mono cameras, whatever their sockets; colour elsewhere than CAM_A.
    odd = _features((D, COLOR, "IMX462"), (B, MONO, "OV9282"), (C, MONO, "OV9282"))
    assert choose_sockets(odd, dai.CalibrationHandler()) == Sockets(left=B, right=C, color=D)
    with pytest.raises(SourceNotFound, match="no stereo pair"):
        choose_sockets(_features((A, COLOR, "IMX378")), dai.CalibrationHandler())


class Wiring:
    """A dai.Pipeline whose nodes are mocks restricted to the installed classes' attributes.

    ``create_autospec`` restricts methods; pybind properties (outputs, inputs, initialConfig) come
    out unrestricted, so they are set here to spec'd mocks of their real types, after checking
    that the real class has them. Every ``Output.link(Input)`` is recorded as (output, input) labels.
    """

    PROPS = {
        dai.node.StereoDepth: {"depth": dai.Node.Output, "confidenceMap": dai.Node.Output,
                               "rectifiedLeft": dai.Node.Output, "disparity": dai.Node.Output,
                               "inputAlignTo": dai.Node.Input, "initialConfig": dai.StereoDepthConfig},
        dai.node.ImageAlign: {"input": dai.Node.Input, "inputAlignTo": dai.Node.Input,
                              "outputAligned": dai.Node.Output},
        dai.node.Sync: {"out": dai.Node.Output},
        dai.node.Camera: {},
    }

    def __init__(self) -> None:
        self.links: list[tuple[str, str]] = []
        self.nodes: dict[str, list] = {}
        self.pipeline = mock.create_autospec(dai.Pipeline, instance=True)
        self.pipeline.create.side_effect = self._create

    def _output(self, label: str):
        out = mock.create_autospec(dai.Node.Output, instance=True)
        out.link.side_effect = lambda inp: self.links.append((label, inp._label))
        return out

    def _input(self, label: str):
        inp = mock.create_autospec(dai.Node.Input, instance=True)
        inp._label = label
        return inp

    def _create(self, cls):
        assert cls in self.PROPS, f"unexpected node {cls}"
        name = cls.__name__
        label = f"{name}{len(self.nodes.get(name, []))}"
        node = mock.create_autospec(cls, instance=True)
        if hasattr(cls, "build"):
            node.build.return_value = node
        for prop, kind in self.PROPS[cls].items():
            assert hasattr(cls, prop), f"{name}.{prop} does not exist in depthai {dai.__version__}"
            if kind is dai.Node.Output:
                setattr(node, prop, self._output(f"{label}.{prop}"))
            elif kind is dai.Node.Input:
                setattr(node, prop, self._input(f"{label}.{prop}"))
            else:
                setattr(node, prop, mock.create_autospec(kind, instance=True))
        if cls is dai.node.Camera:
            node.requestOutput.side_effect = lambda *a, **k: self._output(f"{label}.out")
        if cls is dai.node.Sync:
            node.inputs = {k: self._input(f"sync.{k}") for k in ("rgb", "depth", "conf")}
        self.nodes.setdefault(name, []).append(node)
        return node

    def into(self, target: str) -> set[str]:
        return {src for src, dst in self.links if dst == target}


def _wire(platform, sockets: Sockets, config: OakConfig = OakConfig()) -> Wiring:
    w = Wiring()
    OakSource(config)._build(w.pipeline, platform, sockets)
    return w


@pytest.mark.parametrize("platform", [dai.Platform.RVC2, dai.Platform.RVC4])
def test_wiring_colour_aligned(platform):
    """Defects 2, 3, 5, 8 and 7 on both platforms, through OakSource._build."""
    w = _wire(platform, Sockets(left=B, right=C, color=A))
    cams = w.nodes["Camera"]
    assert [c.build.call_args.args[0] for c in cams] == [B, C, A]
    stereo = w.nodes["StereoDepth"][0]
    assert stereo.build.call_args.args[2] == dai.node.StereoDepth.PresetMode.DEFAULT
    # 2: nothing the user left unset overrides the preset
    for setter in ("setExtendedDisparity", "setSubpixel", "setLeftRightCheck", "setSubpixelFractionalBits"):
        getattr(stereo, setter).assert_not_called()
        getattr(stereo.initialConfig, setter).assert_not_called()
    stereo.initialConfig.setDepthUnit.assert_called_once_with(dai.LengthUnit.MILLIMETER)
    # 5: automatic calibration explicitly off
    w.pipeline.setAutoCalibrationMode.assert_called_once_with(dai.Pipeline.AutoCalibrationMode.OFF)
    # 8: newest wins
    w.nodes["Sync"][0].out.createOutputQueue.assert_called_once_with(maxSize=1, blocking=False)
    # 3: no confidence map is delivered when it cannot be registered to colour
    assert not any(src.endswith("confidenceMap") for src, _ in w.links)
    assert w.into("sync.conf") == set()
    assert w.into("sync.rgb") == {"Camera2.out"}
    if platform == dai.Platform.RVC4:
        assert w.into("sync.depth") == {"ImageAlign0.outputAligned"}
        assert w.into("ImageAlign0.input") == {"StereoDepth0.depth"}
        assert w.into("ImageAlign0.inputAlignTo") == {"Camera2.out"}
        assert len(w.nodes["ImageAlign"]) == 1
    else:
        assert w.into("sync.depth") == {"StereoDepth0.depth"}
        assert w.into("StereoDepth0.inputAlignTo") == {"Camera2.out"}
        assert "ImageAlign" not in w.nodes


@pytest.mark.parametrize("platform", [dai.Platform.RVC2, dai.Platform.RVC4])
def test_wiring_left_aligned_delivers_registered_confidence(platform):
    cfg = OakConfig(preset="HIGH_DETAIL", extended_disparity=True, subpixel=False, confidence_threshold=100,
                    auto_calibration="on_start")
    w = _wire(platform, Sockets(left=B, right=C, color=None), cfg)
    stereo = w.nodes["StereoDepth"][0]
    assert len(w.nodes["Camera"]) == 2
    stereo.setDepthAlign.assert_called_once_with(dai.StereoDepthConfig.AlgorithmControl.DepthAlign.RECTIFIED_LEFT)
    assert w.into("sync.rgb") == {"StereoDepth0.rectifiedLeft"}
    assert w.into("sync.depth") == {"StereoDepth0.depth"}
    assert w.into("sync.conf") == {"StereoDepth0.confidenceMap"}
    stereo.initialConfig.setExtendedDisparity.assert_called_once_with(True)
    stereo.initialConfig.setSubpixel.assert_called_once_with(False)
    stereo.initialConfig.setLeftRightCheck.assert_not_called()
    stereo.initialConfig.setConfidenceThreshold.assert_called_once_with(100)
    w.pipeline.setAutoCalibrationMode.assert_called_once_with(dai.Pipeline.AutoCalibrationMode.ON_START)


def test_pipeline_default_auto_calibration_is_on_start():
    """Why defect 5 needs the explicit call: DepthAI 3.12's own default would recalibrate at start."""
    assert dai.Pipeline(False).getAutoCalibrationMode() == dai.Pipeline.AutoCalibrationMode.ON_START


def test_oak_module_type_checks_against_depthai_stubs():
    """Defect 9: mypy on device/sources/oak.py against the stubs depthai ships catches v2-era calls."""
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--follow-imports=silent", "--ignore-missing-imports",
         "--no-incremental", "--cache-dir", os.devnull, str(root / "device" / "sources" / "oak.py")],
        capture_output=True, text=True, cwd=root, timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
