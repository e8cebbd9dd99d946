"""`depthruler measure` with the shape options (--box, --height [--on], --path/--area with --point)
on a recording of a simulated box on a floor (640x360), against the box's truth."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from cli.main import app
from device import SourceInfo
from device.formats.recording import RecordingWriter
from sim.shapes import box_case

W, H = 640, 360


@pytest.fixture(scope="module")
def box_recording(tmp_path_factory):
    case = box_case(1, range_m=1.0, variant="plain", width=W, height=H)
    out = tmp_path_factory.mktemp("shapes") / "rec"
    with RecordingWriter(out, SourceInfo(kind="sim", name="box", width=W, height=H, fps=30.0)) as rec:
        rec.write(case.frame)
    return case, out


def _xy(p) -> str:
    return f"{p[0]:.0f},{p[1]:.0f}"


def _run(rec, *args):
    return CliRunner().invoke(app, ["measure", f"replay:{rec}", *args])


def test_box_json_and_text(box_recording):
    case, rec = box_recording
    res = _run(rec, "--box", _xy(case.click_px), "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["kind"] == "box" and out["frame"] == 0
    truth = (case.length_m, case.width_m, case.height_m)
    for key, t in zip(("length_m", "width_m", "height_m"), truth):
        assert out[key] == pytest.approx(t, rel=0.05), key
    assert len(out["uncertainty_m"]) == 3 and len(out["corners_m"]) == 4 and out["quality"] in ("good", "check")
    text = _run(rec, "--box", _xy(case.click_px))
    assert text.exit_code == 0, text.output
    assert f"{out['height_m']:.4f}" in text.stdout and "(length x width x height)" in text.stdout
    assert "quality: " in text.stdout and "95 % interval" in text.stdout


def test_height_above_the_floor_found_or_named(box_recording):
    case, rec = box_recording
    found = json.loads(_run(rec, "--height", _xy(case.click_px), "--json").stdout)
    assert found["kind"] == "height" and found["value"] == pytest.approx(case.height_m, rel=0.02)
    named = _run(rec, "--height", _xy(case.click_px), "--on", f"{case.click_px[0]:.0f},{H - 20}", "--json")
    assert named.exit_code == 0, named.output
    assert json.loads(named.stdout)["value"] == pytest.approx(case.height_m, rel=0.03)
    text = _run(rec, "--height", _xy(case.click_px))
    assert text.stdout.startswith(f"height {found['value']:.4f} m ± ")


def test_path_and_area_from_points(box_recording):
    case, rec = box_recording
    corners = [_xy(p) for p in case.corners_px]
    # Clicks just inside the top face's corners, towards its centre.
    cx, cy = case.click_px
    inner = [f"{cx + 0.8 * (p[0] - cx):.0f},{cy + 0.8 * (p[1] - cy):.0f}" for p in case.corners_px]
    args = [a for c in inner for a in ("--point", c)]
    path = _run(rec, "--path", *args, "--json")
    assert path.exit_code == 0, path.output
    p = json.loads(path.stdout)
    assert p["kind"] == "path" and len(p["parts"]) == 3 and p["value"] == pytest.approx(sum(p["parts"]))
    area = _run(rec, "--area", *args, "--json")
    assert area.exit_code == 0, area.output
    a = json.loads(area.stdout)
    assert a["unit"] == "m2" and a["value"] == pytest.approx(0.64 * case.length_m * case.width_m, rel=0.1)
    assert "legs " in _run(rec, "--path", *args).stdout
    assert len(corners) == 4


@pytest.mark.parametrize("args, fragment, code", [
    (["--box", "10,10", "--p1", "1,1", "--p2", "5,5"], "choose one", 2),
    ([], "say what to measure", 2),
    (["--area", "--point", "10,10", "--point", "50,50"], "at least 3", 1),
    (["--point", "10,10", "--box", "30,30"], "--path or --area", 2),
    (["--box", "30;30"], "X,Y", 2),
    (["--box", "900,30"], "outside", 1),
    (["--p1", "10,10"], "both --p1 and --p2", 2),
])
def test_shape_bad_input(box_recording, args, fragment, code):
    _, rec = box_recording
    res = _run(rec, *args)
    assert res.exit_code == code, res.output
    assert fragment in res.output


def test_box_click_on_the_floor_is_an_error(box_recording):
    case, rec = box_recording
    res = _run(rec, "--box", f"{case.click_px[0]:.0f},{H - 10}")
    assert res.exit_code == 1 and "top face" in res.output
