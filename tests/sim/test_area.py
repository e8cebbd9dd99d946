"""Area of a framed panel on a wall on the simulator (sim.shapes panel cases, 640x360, 0.6-3 m),
clicked at its corners; a polygon across two surfaces is "unreliable", two clicks are refused."""

from __future__ import annotations

import numpy as np
import pytest

from measure import MeasureError
from measure.area import measure_area
from sim.shapes import box_case, panel_case

W, H = 640, 360


@pytest.fixture(scope="module")
def areas():
    out = []
    for seed in range(8):
        case = panel_case(seed, width=W, height=H)
        out.append((case, measure_area(case.frame, case.clicks_px)))
    return out


def test_panel_area_matches_the_scene(areas):
    err = np.array([100 * (m.value - c.area_m2) / c.area_m2 for c, m in areas])
    assert np.median(np.abs(err)) <= 2.0, err
    assert np.abs(err).max() <= 5.0, err
    z = np.array([abs(m.value - c.area_m2) / m.uncertainty for c, m in areas])
    assert np.mean(z <= 2.0) >= 0.75, z
    for _, m in areas:
        assert m.kind == "area" and m.unit == "m2" and len(m.points_m) == 4
        assert m.quality in ("good", "check")


def test_panel_area_sigma_holds_a_calibration_offset(areas):
    """A disparity offset common to the frame (``CALIBRATION_PX``) scales the panel's corners along
    their rays together with its plane; the one-sigma is at least the area it moves."""
    from dataclasses import replace

    from measure.planes import CALIBRATION_PX

    for case, m in areas[:4]:
        moved = replace(case.frame, disparity=case.frame.disparity + np.float32(CALIBRATION_PX))
        shift = abs(measure_area(moved, case.clicks_px).value - m.value)
        assert shift > 0.005 * m.value, shift  # the offset does move the answer
        assert m.uncertainty >= 0.8 * shift, (m.uncertainty, shift)


def test_polygon_over_a_box_and_the_floor_is_unreliable():
    case = box_case(1, range_m=1.0, variant="plain", width=W, height=H)
    x, y = case.click_px
    # Half on the box's top, half on the floor below it in the image.
    poly = [(x - 40, y), (x + 40, y), (x + 40, H - 5), (x - 40, H - 5)]
    m = measure_area(case.frame, poly)
    assert m.quality == "unreliable"
    assert any("one plane" in r for r in m.reasons), m.reasons


def test_polygon_of_two_points_is_refused():
    case = panel_case(0, width=W, height=H)
    with pytest.raises(MeasureError, match="at least 3"):
        measure_area(case.frame, case.clicks_px[:2])


def test_crossed_polygon_is_refused():
    case = panel_case(0, width=W, height=H)
    a, b, c, d = case.clicks_px
    with pytest.raises(MeasureError, match="cross"):
        measure_area(case.frame, [a, c, b, d])
