"""The OAK source without a device: finding it (absent, busy, wrong id, no USB permission), spec parsing,
the type check against depthai's stubs, and the hardware test."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from device import SourceError, SourceNotFound, SourceSpec, open_source
from device.sources.oak import UDEV_RULE, OakConfig, config_from_spec

import depthai as dai  # noqa: E402  (device.sources.oak has set DEPTHAI_LEVEL / DEPTHAI_SEARCH_TIMEOUT)


@pytest.mark.slow
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
    with pytest.raises(SourceError, match="unknown oak option 'colour'"):
        config_from_spec(SourceSpec.parse("oak?colour=1"))
    with pytest.raises(SourceError, match="fps"):
        config_from_spec(SourceSpec.parse("oak?fps=abc"))
    with pytest.raises(SourceError, match="confidence_threshold=300 must be a whole number from 0 to 255"):
        OakConfig(confidence_threshold=300)


@pytest.mark.hardware
def test_real_oak_delivers_registered_frames():
    with open_source("oak") as src:
        frame = src.read(timeout_s=5.0)
    assert frame.image.shape[:2] == frame.disparity.shape == (720, 1280)
    assert 0.02 < frame.baseline_m < 0.2
    assert np.isfinite(frame.disparity).mean() > 0.2


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
    import device.sources.oak.source as oak_source
    from device import SourceInfo

    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices", staticmethod(lambda skipInvalidDevices=True: []))
    monkeypatch.setattr(oak_source, "list_usb", lambda: [SourceInfo(kind="usb", name="Luxonis OAK (Movidius)", state="unbooted",
                                                             extra={"usb_id": "03e7:2485"})])
    with pytest.raises(SourceNotFound, match="03e7:2485.*udev") as err:
        find_device("", 100)
    assert UDEV_RULE in str(err.value)
    monkeypatch.setattr(oak_source, "list_usb", lambda: [])
    with pytest.raises(SourceNotFound, match="plug an OAK"):
        find_device("", 100)


@pytest.mark.slow
def test_oak_module_type_checks_against_depthai_stubs():
    """Defect 9: mypy on device/sources/oak/ against the stubs depthai ships catches v2-era calls."""
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run(
        [sys.executable, "-m", "mypy", "--follow-imports=silent", "--ignore-missing-imports",
         "--no-incremental", "--cache-dir", os.devnull, str(root / "device" / "sources" / "oak")],
        capture_output=True, text=True, cwd=root, timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_open_states_the_measurement_depth_settings_in_info_and_recording(monkeypatch, tmp_path):
    """OakSource.open on a stand-in device (real calibration, real output queue): SourceInfo.extra
    states the depth post-processing, frames say it, and a recording's manifest keeps it."""
    import json
    from unittest import mock

    import device.sources.oak.source as oak_source
    from device.formats.recording import RecordingWriter
    from device.sources.oak import OakSource

    from oak_helpers import FIXTURE, A, B, C, Wiring, default_preset_config, features, img

    w = Wiring(default_preset_config(dai.Platform.RVC2))
    queue = dai.MessageQueue("sync", 1, False)
    real_create = w.pipeline.create.side_effect

    def create(cls):
        node = real_create(cls)
        if cls is dai.node.Sync:
            node.out.createOutputQueue.return_value = queue
        return node

    w.pipeline.create.side_effect = create
    dev = mock.create_autospec(dai.Device, instance=True)
    dev.readCalibration.return_value = dai.CalibrationHandler(str(FIXTURE))
    dev.getConnectedCameraFeatures.return_value = features((A, dai.CameraSensorType.COLOR, "IMX378"),
                                                           (B, dai.CameraSensorType.MONO, "OV9282"),
                                                           (C, dai.CameraSensorType.MONO, "OV9282"))
    dev.getPlatform.return_value = dai.Platform.RVC2
    dev.getPlatformAsString.return_value = "RVC2"
    dev.getDeviceName.return_value = "OAK-D"
    dev.isClosed.return_value = False
    dev.getUsbSpeed.return_value = dai.UsbSpeed.HIGH
    monkeypatch.setattr(oak_source, "find_device", lambda mxid, timeout_ms: dai.DeviceInfo("1844301011B546F500"))
    monkeypatch.setattr(dai, "Device", lambda info: dev)
    monkeypatch.setattr(dai, "Pipeline", lambda device: w.pipeline)

    group = dai.MessageGroup()
    group["rgb"] = img(np.zeros((72, 128, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    group["depth"] = img(np.full((72, 128), 1200, np.uint16), dai.ImgFrame.Type.RAW16)
    queue.send(group)
    with OakSource(OakConfig(width=128, height=72)) as src:
        depth = src.info.extra["depth"]
        frame = src.read(0.5)
        with RecordingWriter(tmp_path / "rec", src.info) as rec:
            rec.write(frame)
    assert (depth["temporal_filter"], depth["decimation"], depth["hole_filling"], depth["spatial_filter"]) == (False, 1, False, False)
    assert depth["median"] == "KERNEL_7x7" and depth["confidence_threshold"] == 15
    assert frame.meta["depth_postprocessing"] == "measurement"
    assert np.allclose(frame.depth(), 1.2)
    manifest = json.loads((tmp_path / "rec" / "manifest.json").read_text())
    assert manifest["source"]["extra"]["depth"] == depth
    assert src.info.extra["usb_speed"] == "HIGH"  # what `depthruler doctor` judges the link by (HIGH = USB2)
