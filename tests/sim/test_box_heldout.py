"""Boxes of the shapes study's held-out seeds (sim.shapes box cases, 1280x720, as ``depthruler eval shapes
--seed 1000`` draws them) that the method once got wrong: a box standing on a table measured from the
floor beyond it, a side placed at the foot of a side face seen at a grazing angle, a box whose top is
mostly hidden by a taller box beside it. Each case takes a few seconds to render: slow."""

from __future__ import annotations

import numpy as np
import pytest

from measure import MeasureError
from measure.box import measure_box
from measure.height import measure_height
from sim.shapes import box_case


def _errors_pct(case, box) -> np.ndarray:
    truth = np.array([case.length_m, case.width_m, case.height_m])
    return 100.0 * (np.array(box.dimensions_m) - truth) / truth


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1030, 1073, 1136])
def test_box_on_a_table_stands_on_the_table(seed):
    # Beyond the table's edge the floor fills most of the ring around a tall box's top; the box's
    # height was measured from it (+96 to +141 %).
    case = box_case(seed, "paper")
    assert case.support == "table" and case.visible > 0.95
    box = measure_box(case.frame, case.click_px)
    assert abs(_errors_pct(case, box)[2]) <= 2.0, (box.height_m, case.height_m)
    h = measure_height(case.frame, case.click_px)
    assert abs(h.value - case.height_m) / case.height_m <= 0.02, (h.value, case.height_m)
    # The supporting plane found is the table's: its normal and offset against the scene's.
    n_true, o_true = np.array(case.support_plane[:3]), case.support_plane[3]
    n, o = np.array(box.support_plane[:3]), box.support_plane[3]
    assert float(n @ n_true) > np.cos(np.radians(5.0))
    assert abs(o - o_true) <= 0.03 * o_true


@pytest.mark.slow
def test_box_on_a_table_beside_a_taller_box_is_not_measured_from_its_neighbour():
    # The neighbour's top lies 0.11 m below this top, the table 0.67 m: the height came out -84 % and "good".
    case = box_case(1138, "paper")
    box = measure_box(case.frame, case.click_px)
    err = _errors_pct(case, box)
    assert box.quality != "good" or np.abs(err).max() <= 5.0, (box.quality, err)
    assert abs(err[2]) <= 2.0, err


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1027, 1085])
def test_box_side_at_a_crease_is_the_ridge_not_the_side_faces_foot(seed):
    # A side face seen at a grazing angle is a few px wide: its foot's colour step lay in the window
    # searched for the ridge and was taken as the side (width +9 to +13 %).
    case = box_case(seed, "paper")
    box = measure_box(case.frame, case.click_px)
    err = _errors_pct(case, box)
    assert np.abs(err[:2]).max() <= 2.0, err


@pytest.mark.slow
def test_box_mostly_hidden_by_the_box_beside_it_is_not_good():
    # 31 % of the top shows; its centre is hidden by the taller box in front, so the click goes where
    # the top shows. Clicked at its centre, the taller box was measured and scored "good" against this one.
    case = box_case(1053, "stress")
    assert case.variant == "beside" and case.visible < 0.5
    import cv2

    top = np.array(case.corners_px, np.float32).reshape(-1, 1, 2)
    assert cv2.pointPolygonTest(top, tuple(map(float, case.click_px)), True) >= -2.0  # on its own top
    try:
        box = measure_box(case.frame, case.click_px)
    except MeasureError:
        return
    assert box.quality != "good", (box.quality, _errors_pct(case, box))
