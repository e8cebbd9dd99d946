"""Discovery probes fail soft, recognise cameras, and `depthruler devices` reports them."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

import device.discovery as discovery
from device import SourceInfo
from cli.main import app

runner = CliRunner()


def test_v4l2_nodes_listed_with_sysfs_names_in_numeric_order(tmp_path):
    dev, sys = tmp_path / "dev", tmp_path / "sys"
    dev.mkdir()
    for n in (10, 0, 2):
        (dev / f"video{n}").touch()
    (dev / "videoX").touch()  # not a node name
    (sys / "video0").mkdir(parents=True)
    (sys / "video0" / "name").write_text("3D USB Camera: 3D USB Camera\n")
    found = discovery.list_v4l2(sys_root=sys, dev_root=dev, query=lambda _n: "unknown")
    assert [i.serial for i in found] == [str(dev / "video0"), str(dev / "video2"), str(dev / "video10")]
    assert found[0].name == "3D USB Camera: 3D USB Camera" and found[1].name == "video2"
    assert found[0].extra["spec"] == f"v4l2:{dev / 'video0'}"
    assert discovery.list_v4l2(sys_root=sys, dev_root=tmp_path / "missing") == []


def test_uvc_metadata_nodes_are_not_listed_and_permission_is_named(tmp_path):
    dev, sys = tmp_path / "dev", tmp_path / "sys"
    dev.mkdir()
    for n, index in ((0, "0"), (1, "1"), (2, "0"), (3, "1"), (4, "0")):
        (dev / f"video{n}").touch()
        (sys / f"video{n}").mkdir(parents=True)
        (sys / f"video{n}" / "index").write_text(index + "\n")
    caps = {
        "video0": discovery.V4L2_CAP_VIDEO_CAPTURE | 0x04000000,  # capture + streaming
        "video1": 0x00800000 | 0x04000000,  # UVC metadata node: META_CAPTURE, no video
        "video2": "no-permission",
        "video3": "unknown",  # cannot be queried: sysfs index 1 says metadata
        "video4": "unknown",
    }
    found = discovery.list_v4l2(sys_root=sys, dev_root=dev, query=lambda node: caps[node.name])
    assert [i.serial.rsplit("/", 1)[-1] for i in found] == ["video0", "video2", "video4"]
    denied = found[1]
    assert denied.state == "no-permission" and "usermod -aG video" in denied.extra["fix"]
    assert "busy" not in denied.state


def test_querycap_on_something_that_is_not_a_v4l2_node(tmp_path):
    plain = tmp_path / "video0"
    plain.write_text("")
    assert discovery.querycap(plain) == "unknown"  # a file answers no VIDIOC_QUERYCAP


def _usb(vid, pid, iface_classes=(), device_class=0, strings=None):
    strings = strings or {}

    class Dev(SimpleNamespace):
        def __iter__(self):
            return iter([[SimpleNamespace(bInterfaceClass=c) for c in iface_classes]])

        def __getattr__(self, name):
            if name in ("manufacturer", "product", "serial_number"):
                if name not in strings:
                    raise ValueError("The device has no langid (permission denied)")
                return strings[name]
            raise AttributeError(name)

    return Dev(idVendor=vid, idProduct=pid, bDeviceClass=device_class, bus=1, address=4)


def test_usb_cameras_recognised_and_others_ignored():
    oak = discovery.usb_camera_info(_usb(0x03E7, 0x2485))
    assert oak.kind == "usb" and oak.state == "unbooted" and oak.extra["usb_id"] == "03e7:2485"
    assert oak.serial == ""  # string descriptors unreadable without permissions: still listed
    booted = discovery.usb_camera_info(_usb(0x03E7, 0xF63B, strings={"serial_number": "1844301011B546F500"}))
    assert booted.state == "booted" and booted.serial == "1844301011B546F500"
    uvc = discovery.usb_camera_info(
        _usb(0x32E4, 0x9750, iface_classes=(14, 14, 1), strings={"manufacturer": "ELP", "product": "Stereo"})
    )
    assert uvc.name == "ELP Stereo" and uvc.extra["uvc"] is True
    assert discovery.usb_camera_info(_usb(0x046D, 0xC31C, iface_classes=(3,))) is None  # a keyboard


def test_depthai_devices_reported_with_state(monkeypatch):
    import depthai as dai

    info = dai.DeviceInfo("1844301011B546F500")
    info.name = "1.3"  # USB port path
    info.state = dai.XLinkDeviceState.X_LINK_BOOTED
    info.protocol = dai.XLinkProtocol.X_LINK_USB_VSC
    info.platform = dai.XLinkPlatform.X_LINK_MYRIAD_X
    denied = dai.DeviceInfo("1.4")
    denied.status = dai.XLinkError_t.X_LINK_INSUFFICIENT_PERMISSIONS
    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices",
                        staticmethod(lambda skipInvalidDevices=True: [info] + ([] if skipInvalidDevices else [denied])))
    oak, no_perm = discovery.list_depthai()
    assert (oak.kind, oak.serial, oak.state) == ("oak", "1844301011B546F500", "booted")
    assert oak.extra == {"protocol": "usb_vsc", "platform": "myriad_x", "spec": "oak:1844301011B546F500"}
    # A device without USB permission is listed, with the rule that fixes it (not dropped).
    assert no_perm.state == "no-permission" and discovery.OAK_UDEV_RULE in no_perm.extra["fix"]
    monkeypatch.setattr(discovery, "list_devices", lambda: [no_perm])
    result = runner.invoke(app, ["devices"])
    assert "[no-permission]" in result.output and 'ATTRS{idVendor}=="03e7"' in result.output


def test_probes_fail_soft(monkeypatch):
    import depthai as dai
    import libusb_package

    def boom(*_a, **_k):
        raise RuntimeError("XLink init failed")

    monkeypatch.setattr(libusb_package, "get_libusb1_backend", boom)
    assert discovery.list_usb() == []
    monkeypatch.setattr(libusb_package, "get_libusb1_backend", lambda: None)  # no libusb at all
    assert discovery.list_usb() == []
    monkeypatch.setattr(dai.XLinkConnection, "getAllConnectedDevices", boom)
    assert discovery.list_depthai() == []


def test_devices_cli_with_nothing_attached(monkeypatch):
    monkeypatch.setattr(discovery, "list_devices", lambda: [])
    result = runner.invoke(app, ["devices"])
    assert result.exit_code == 0
    assert "no cameras found" in result.output and "depthruler serve --source sim" in result.output
    result = runner.invoke(app, ["devices", "--json"])
    assert result.exit_code == 0
    assert json.loads(result.output) == {"devices": [], "count": 0}


def test_devices_cli_lists_found_devices(monkeypatch):
    found = [
        SourceInfo(kind="oak", name="OAK", serial="1844301011B546F500", state="unbooted",
                   extra={"spec": "oak:1844301011B546F500"}),
        SourceInfo(kind="v4l2", name="3D USB Camera", serial="/dev/video0", extra={"spec": "v4l2:/dev/video0"}),
    ]
    monkeypatch.setattr(discovery, "list_devices", lambda: found)
    result = runner.invoke(app, ["devices"])
    assert result.exit_code == 0
    assert "oak:1844301011B546F500" in result.output and "[unbooted]" in result.output
    assert "v4l2:/dev/video0" in result.output and "no cameras" not in result.output
    data = json.loads(runner.invoke(app, ["devices", "--json"]).output)
    assert data["count"] == 2 and data["devices"][0]["serial"] == "1844301011B546F500"
    assert data["devices"][1]["kind"] == "v4l2"


def test_devices_cli_on_this_machine_exits_zero():
    result = runner.invoke(app, ["devices", "--json"])
    assert result.exit_code == 0
    data = json.loads(result.output)
    assert data["count"] == len(data["devices"])
    if data["count"] == 0:
        plain = runner.invoke(app, ["devices"])
        assert plain.exit_code == 0 and "no cameras found" in plain.output


@pytest.mark.slow
def test_devices_json_stdout_is_clean_in_a_fresh_process():
    """DepthAI prints a USB banner on import unless DEPTHAI_LEVEL is set first: stdout must stay JSON."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {k: v for k, v in os.environ.items() if not k.startswith("DEPTHAI_")}
    out = subprocess.run([sys.executable, "-m", "cli.main", "devices", "--json"], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[2], env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["count"] >= 0


@pytest.mark.hardware
def test_attached_camera_is_discovered():
    assert any(i.kind in ("oak", "v4l2") for i in discovery.list_devices())
