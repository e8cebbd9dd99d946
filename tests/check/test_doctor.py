"""`depthruler doctor` on the simulator, a recording made by `depthruler record`, a `video:` stereo file and a
fake sysfs: every check reports, and the findings carry the numbers (fps, fill, baseline) they are judged on."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from check.doctor import NO_CAMERA, run_doctor
from check.doctor.calib import baseline_finding, rectification_finding
from check.doctor.host import usb_findings, with_depthai_speed
from check.doctor.stream import Window, timestamps_finding
from device.base import SourceInfo
from device.calibration.files import CalibrationRef
from device.formats.recording import RecordingWriter
from factories import synthetic_frame, write_video

runner = CliRunner()
CHECKS = ["versions", "usb-speed", "usb-permission", "open", "frames", "timestamps", "registration", "fill", "baseline",
          "intrinsics", "rectification", "board"]
BOARD_SIM = "sim:charuco?distance=1.2&width=640&height=360&fps=10"


def test_sim_reports_every_check_with_fps_fill_and_the_board():
    report = run_doctor(BOARD_SIM, window_s=1.0)
    assert [f.check for f in report.findings] == CHECKS
    frames = report.get("frames")
    # pass, or warn on a host too loaded to render 10 fps: never a fail, and the rate is a number
    assert frames.status in ("pass", "warn") and frames.figures["frames"] >= 3 and frames.figures["fps"] > 0
    fill = report.get("fill").figures
    assert 0.5 < fill["fill_rate"] <= 1.0 and 0.5 < fill["centre_fill_rate"] <= 1.0
    assert report.get("baseline").status == "pass" and report.get("baseline").figures["baseline_m"] == pytest.approx(0.06)
    stamps = report.get("timestamps")
    assert report.get("usb-speed").status == "skip" and stamps.status != "fail" and stamps.figures["backwards"] == 0
    board = report.get("board")
    assert board.status in ("pass", "warn") and board.figures["pairs"] >= 50  # the scene's own 7x5 board was found
    assert abs(board.figures["bias_pct"]) < 2.0


def test_a_wrong_board_in_view_is_a_warning_naming_the_options():
    from device.calibration.board import BoardSpec

    report = run_doctor(BOARD_SIM, window_s=0.2, board=BoardSpec(11, 8, 0.03, 0.022, "DICT_5X5_100"))
    board = report.get("board")
    assert board.status == "warn" and board.figures["markers"] > 0 and "--squares" in board.fix


def _recording(path, frames, info):
    with RecordingWriter(path, info) as w:
        for f in frames:
            w.write(f)
    return path


def test_a_recording_from_depthruler_record(tmp_path):
    from cli.main import app

    rec = tmp_path / "rec"
    res = runner.invoke(app, ["record", "--source", "sim:poster?distance=2&width=320&height=180&fps=0", "--out", str(rec),
                              "--frames", "4"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["doctor", "--source", f"replay:{rec}", "--window", "5", "--json"])
    out = json.loads(res.output.strip().splitlines()[-1])
    by = {f["check"]: f for f in out["findings"]}
    assert [f["check"] for f in out["findings"]] == CHECKS
    assert by["frames"]["figures"]["frames"] == 4 and by["frames"]["figures"]["ended"] is True
    assert by["frames"]["figures"]["fps"] > 0 and by["timestamps"]["status"] == "pass"
    assert 0.3 < by["fill"]["figures"]["fill_rate"] <= 1.0
    assert by["baseline"]["status"] == "pass" and by["board"]["status"] == "skip"
    assert res.exit_code == 0 and out["status"] in ("pass", "warn")


def test_a_baseline_in_board_squares_fails_naming_the_unit(tmp_path):
    """A 60 mm pair calibrated with OpenCV's default square size 1 and 25 mm squares: T = 2.4 (squares), read as metres."""
    frames = [dataclasses.replace(synthetic_frame(k), baseline_m=2.4) for k in range(3)]
    rec = _recording(tmp_path / "rec", frames, SourceInfo(kind="v4l2", name="pair", serial="S", fps=30.0))
    report = run_doctor(f"replay:{rec}", window_s=2.0)
    base = report.get("baseline")
    assert base.status == "fail" and report.status == "fail"
    assert base.figures["baseline_m"] == pytest.approx(2.4) and "squares" in base.fix and "record again" in base.fix
    in_mm = baseline_finding(dataclasses.replace(frames[0], baseline_m=60.0), "video", CalibrationRef(path="stereo.yaml"))
    assert in_mm.status == "fail" and "calib_units=mm" in in_mm.fix and "60.0 mm" in in_mm.fix
    assert baseline_finding(dataclasses.replace(frames[0], baseline_m=0.075), "oak", None).status == "pass"


def test_timestamps_backwards_fail_and_drops_warn():
    info = SourceInfo(kind="oak", name="OAK", fps=30.0)

    def window(stamps):
        return Window(info, tuple(range(len(stamps))), tuple(stamps), None, (), 1.0)

    assert timestamps_finding(window([0.0, 0.033, 0.066, 0.05, 0.1])).status == "fail"
    drops = timestamps_finding(window([i / 30 for i in range(10)] + [i / 30 for i in range(14, 24)]))
    assert drops.status == "warn" and drops.figures["dropped"] == 4
    even = timestamps_finding(window([i / 30 for i in range(30)]))
    assert even.status == "pass" and even.figures["device_fps"] == pytest.approx(30.0)
    free = Window(SourceInfo(kind="sim", name="sim", fps=0.0), (0, 1, 2, 3), (0.0, 0.1, 0.5, 0.6), None, (), 1.0)
    assert timestamps_finding(free).figures["dropped"] == 0  # no rate stated: nothing was due, nothing dropped
    from check.doctor import Finding

    assert Finding("fill", "warn", "x", figures={"fov_deg": float("nan")}).to_dict()["figures"]["fov_deg"] is None


def _usb_device(root, name, vid, pid, speed, bus=1, dev=2, uvc=False):
    d = root / name
    d.mkdir(parents=True)
    for k, v in {"idVendor": vid, "idProduct": pid, "speed": speed, "busnum": bus, "devnum": dev, "product": "cam"}.items():
        (d / k).write_text(f"{v}\n")
    intf = d / f"{name}:1.0"
    intf.mkdir()
    (intf / "bInterfaceClass").write_text("0e\n" if uvc else "ff\n")


def test_usb_speed_and_permission_from_sysfs(tmp_path):
    sys_root, dev_root = tmp_path / "sys", tmp_path / "dev"
    _usb_device(sys_root, "2-1", "03e7", "f63b", 480, bus=2, dev=5)
    (dev_root / "002").mkdir(parents=True)
    (dev_root / "002" / "005").write_text("")
    speed, perm = usb_findings("oak", sys_root, dev_root)
    assert speed.status == "warn" and "USB2" in speed.measured and "USB3 port" in speed.fix and speed.figures["speed_mbps"] == [480.0]
    assert perm.status == "pass"
    (sys_root / "2-1" / "speed").write_text("5000\n")
    (sys_root / "2-1" / "devnum").write_text("9\n")  # a node that is not there: this user cannot open it
    speed, perm = usb_findings("oak", sys_root, dev_root)
    assert speed.status == "pass" and perm.status == "fail" and "udev" in perm.fix
    assert [f.status for f in usb_findings("oak", tmp_path / "empty-sys", dev_root)] == ["warn", "warn"]
    (tmp_path / "bare").mkdir()
    assert usb_findings("oak", tmp_path / "bare", dev_root)[0].status == "fail"  # no OAK on the bus
    assert usb_findings("replay", sys_root, dev_root)[0].status == "skip"
    (sys_root / "2-1" / "idProduct").write_text("2485\n")  # unbooted: enumerates at USB2 until DepthAI boots it
    (sys_root / "2-1" / "speed").write_text("480\n")
    assert usb_findings("oak", sys_root, dev_root)[0].status == "skip"
    # what DepthAI says of the open OAK (dai.UsbSpeed): a USB2 link warns even where sysfs is not visible
    blind = usb_findings("oak", tmp_path / "empty-sys", dev_root)[0]
    assert with_depthai_speed(blind, "UsbSpeed.HIGH").status == "warn" and with_depthai_speed(blind, "SUPER").status == "pass"
    assert with_depthai_speed(speed, "HIGH").figures["depthai_usb_speed"] == "HIGH" and with_depthai_speed(speed, "HIGH").status == "warn"


def _opencv_yaml(path, k, t_x, size):
    """A stereo calibration as OpenCV's stereo_calib sample writes it (M1, D1, M2, D2, R, T; T in the board's unit)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (("M1", k), ("D1", np.zeros((1, 5))), ("M2", k), ("D2", np.zeros((1, 5))), ("R", np.eye(3)),
                        ("T", np.array([[-t_x], [0.0], [0.0]]))):
        fs.write(name, np.asarray(value, np.float64))
    fs.write("image_width", size[0])
    fs.write("image_height", size[1])
    fs.release()
    return path


def test_a_video_stereo_file_with_an_opencv_yaml(tmp_path):
    from factories import rendered_pair

    pair = rendered_pair("poster", 2.0)
    h, w = pair.left.shape[:2]
    yaml = _opencv_yaml(tmp_path / "stereo.yaml", pair.k, pair.baseline_m, (w, h))
    video = write_video(tmp_path / "pair.mkv", [np.hstack([pair.left, pair.right])] * 3)
    report = run_doctor(f"video:{video}?layout=side-by-side&calib={yaml}&ndisp={pair.ndisp}", window_s=5.0)
    assert [f.check for f in report.findings] == CHECKS
    assert report.get("open").status == "pass" and report.get("frames").figures["frames"] == 3
    assert report.get("fill").figures["fill_rate"] > 0.3
    assert report.get("baseline").figures["baseline_m"] == pytest.approx(pair.baseline_m)
    rect = report.get("rectification")
    assert rect.status == "warn" and "no RMS" in rect.measured  # OpenCV's sample files carry none
    # OpenCV's stereo_calib sample with its default square size 1 and 25 mm squares writes T in squares (2.4 for 60 mm)
    squares = _opencv_yaml(tmp_path / "squares.yaml", pair.k, pair.baseline_m / 0.025, (w, h))
    bad = run_doctor(f"video:{video}?layout=side-by-side&calib={squares}&ndisp={pair.ndisp}", window_s=0.5)
    failed = [f for f in bad.findings if f.status == "fail"]
    assert bad.status == "fail" and failed[0].check in ("baseline", "open")  # read as 2.4 m, or refused when loaded
    assert "squares" in failed[0].fix + failed[0].measured or "calib_units" in failed[0].fix + failed[0].measured
    # the project's JSON carries its RMS: 1.4 px is a calibration to redo
    from device.calibration.files import load_any

    calib = dataclasses.replace(load_any(str(yaml)), rms=1.4)
    calib.save(tmp_path / "c.json")
    assert rectification_finding("video", CalibrationRef(path=str(tmp_path / "c.json"))).status == "fail"
    calib = dataclasses.replace(calib, rms=0.21)
    calib.save(tmp_path / "c.json")
    good = rectification_finding("video", CalibrationRef(path=str(tmp_path / "c.json")))
    assert good.status == "pass" and good.figures["rms_px"] == pytest.approx(0.21)


def test_no_camera_says_so_in_one_line(monkeypatch):
    import check.doctor.run as doctor_run
    from cli.main import app

    monkeypatch.setattr(doctor_run, "list_devices", lambda: [])
    res = runner.invoke(app, ["doctor"])
    assert res.exit_code == 1 and res.output.strip() == NO_CAMERA and "plug in an OAK" in NO_CAMERA


def test_a_source_that_does_not_open_fails_and_skips_the_rest(tmp_path):
    report = run_doctor(f"replay:{tmp_path / 'nothing'}", window_s=0.5)
    assert report.get("open").status == "fail" and report.status == "fail"
    assert [f.check for f in report.findings] == CHECKS
    assert {f.status for f in report.findings[CHECKS.index("frames"):]} == {"skip"}


def test_a_camera_source_without_a_camera_says_so_first_in_one_line(monkeypatch):
    """`doctor --source oak` on a machine with no camera: the first line is the no-camera line (what to plug
    in), the checks follow; with a camera of another kind attached the open finding alone names it."""
    import check.doctor.run as doctor_run
    from cli.main import app
    from device.errors import SourceNotFound

    class Absent:
        def open(self):
            raise SourceNotFound("no OAK camera found within 1.0 s; plug an OAK camera into a USB3 port")

    monkeypatch.setattr(doctor_run, "make_source", lambda spec: Absent())
    monkeypatch.setattr(doctor_run, "list_devices", lambda: [])
    res = runner.invoke(app, ["doctor", "--source", "oak"])
    lines = res.stdout.strip().splitlines()  # progress goes to stderr
    assert res.exit_code == 1 and lines[0] == NO_CAMERA and lines[1].startswith("doctor FAIL: oak")
    assert any(line.startswith("[fail] open: oak does not open: no OAK camera found") for line in lines)
    out = json.loads(runner.invoke(app, ["doctor", "--source", "oak", "--json"]).output.strip().splitlines()[-1])
    assert out["message"] == NO_CAMERA and out["status"] == "fail"
    webcam = SourceInfo(name="USB webcam", kind="v4l2", serial="", width=640, height=480, fps=30.0, extra={})
    monkeypatch.setattr(doctor_run, "list_devices", lambda: [webcam])
    report = run_doctor("oak", window_s=0.1)
    assert report.note == "" and report.get("open").status == "fail" and "message" not in report.to_dict()


def test_a_refused_calibration_is_fixed_in_the_calibration_and_the_unit_is_named(tmp_path):
    """T in board squares is refused when the file loads: the fix points at the calibration, not at the
    spec's file name; a file read with calib_units states that unit, one without it the file's or metres."""
    from factories import rendered_pair

    pair = rendered_pair("poster", 2.0)
    h, w = pair.left.shape[:2]
    video = write_video(tmp_path / "pair.mkv", [np.hstack([pair.left, pair.right])] * 2)
    spec = f"video:{video}?layout=side-by-side&ndisp={pair.ndisp}&calib="
    squares = _opencv_yaml(tmp_path / "squares.yaml", pair.k, pair.baseline_m / 0.025, (w, h))
    opened = run_doctor(spec + str(squares), window_s=0.1).get("open")
    assert opened.status == "fail" and "calib_units=" in opened.measured
    assert "calibration is refused" in opened.fix and "name the file" not in opened.fix
    metres = _opencv_yaml(tmp_path / "m.yaml", pair.k, pair.baseline_m, (w, h))
    for extra, unit in (("", "T in the file's units, else metres"), ("&calib_units=m", "T in calib_units=m")):
        base = run_doctor(spec + str(metres) + extra, window_s=0.1).get("baseline")
        assert base.status == "pass" and unit in base.measured and "None" not in base.measured
        assert base.figures["baseline_m"] == pytest.approx(pair.baseline_m)
