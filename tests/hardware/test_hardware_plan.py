"""The hardware test plan (tests/hardware/README.md), in the order a person runs it with a camera attached:
the doctor, the board check, then one known length. Every test here is marked ``hardware`` and skipped
unless DEPTHRULER_HARDWARE=1; DEPTHRULER_HW_SOURCE names the source (default: the attached camera),
DEPTHRULER_CHECK_BOARD the printed board as "7x5,40,30,DICT_5X5_100" (squares, square mm, marker mm,
dictionary) and DEPTHRULER_KNOWN_LENGTH a length on the view as "x1,y1,x2,y2,metres" (pixels of the colour image)."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytestmark = pytest.mark.hardware


def hw_source() -> str:
    from check.doctor import NO_CAMERA, attached_source

    spec = os.environ.get("DEPTHRULER_HW_SOURCE") or attached_source()
    if spec is None:
        pytest.fail(NO_CAMERA)
    return spec


def hw_board():
    from device.calibration.board import BoardSpec

    squares, square, marker, dictionary = os.environ.get("DEPTHRULER_CHECK_BOARD", "7x5,40,30,DICT_5X5_100").split(",")
    sx, sy = (int(v) for v in squares.lower().split("x"))
    return BoardSpec(sx, sy, float(square) / 1000, float(marker) / 1000, dictionary)


def test_1_doctor_passes_on_the_camera():
    """Step 1: nothing fails; frames arrive at 80 % of the asked rate or better, in time order, with depth on the view."""
    from check.doctor import run_doctor

    spec = hw_source()
    report = run_doctor(spec, window_s=10.0, board=hw_board())
    lines = "\n".join(f"[{f.status}] {f.check}: {f.measured} | {f.fix}" for f in report.findings)
    print(lines)
    assert report.status != "fail", lines
    frames = report.get("frames").figures
    assert frames["frames"] >= 20 and frames["fps"] > 0
    if frames["nominal_fps"]:
        assert frames["fps"] >= 0.8 * frames["nominal_fps"], lines
    assert report.get("timestamps").figures["backwards"] == 0
    assert report.get("fill").figures["centre_fill_rate"] >= 0.6, lines
    if spec.startswith("oak"):
        assert report.get("usb-speed").status == "pass", lines  # a USB3 link


def test_2_board_check_within_one_percent():
    """Step 2: the printed board at 0.5-1.5 m: bias within 1 %, the truth inside the 95 % interval for 80 % of pairs."""
    from check.run import check_frames
    from device import open_source

    with open_source(hw_source()) as src:
        frames = [src.read(5.0) for _ in range(5)]
    done = check_frames(frames, hw_board(), picture=False)
    fig = done.report["figures"]
    print({k: fig[k] for k in ("pairs", "distance_m", "bias_pct", "spread_pct", "interval_coverage", "fill_rate")})
    assert fig["frames_with_board"] >= 3 and fig["pairs"] >= 50
    assert abs(fig["bias_pct"]) <= 1.0 and fig["interval_coverage"] >= 0.8


def test_3_a_known_length():
    """Step 3: a length measured with a tape (a door's width, an A4 sheet's 297 mm) comes out inside its 95 % interval."""
    from device import open_source
    from measure import measure_distance

    given = os.environ.get("DEPTHRULER_KNOWN_LENGTH")
    if not given:
        pytest.skip("set DEPTHRULER_KNOWN_LENGTH=x1,y1,x2,y2,metres (the ends' pixels from the page's depth readout)")
    x1, y1, x2, y2, truth = (float(v) for v in given.split(","))
    with open_source(hw_source()) as src:
        got = [measure_distance(src.read(5.0), (x1, y1), (x2, y2)) for _ in range(5)]
    values = np.array([m.distance_m for m in got])
    print(f"known {truth:.4f} m: measured {np.round(values, 4).tolist()}, intervals {[m.interval_m for m in got]}")
    inside = sum(m.interval_m[0] <= truth <= m.interval_m[1] for m in got)
    assert inside >= 4 and abs(np.median(values) / truth - 1) <= 0.02
