"""A path (polyline) on the simulator: its value is the sum of its legs measured alone, its one-sigma
their combination with the shared ends' correlation (Eq. 14), and it follows the panel's true outline."""

from __future__ import annotations

import math

import numpy as np
import pytest

from measure import MeasureError, measure_distance
from measure.path import measure_path, path_sigma
from sim.shapes import panel_case

W, H = 640, 360


def _legs(frame, pts):
    return [measure_distance(frame, pts[k], pts[k + 1]) for k in range(len(pts) - 1)]


@pytest.mark.parametrize("seed", [0, 3])
def test_path_is_the_sum_of_its_legs(seed):
    case = panel_case(seed, width=W, height=H)
    pts = list(case.clicks_px[:3])
    path = measure_path(case.frame, pts)
    legs = _legs(case.frame, pts)
    assert path.value == pytest.approx(sum(m.distance_m for m in legs), rel=1e-12)
    assert path.parts == pytest.approx([m.distance_m for m in legs])
    # Eq. 14 by hand: a right-angle turn shares an end whose errors are uncorrelated across the legs.
    u = np.subtract(legs[0].p2_m, legs[0].p1_m)
    v = np.subtract(legs[1].p2_m, legs[1].p1_m)
    cos = u @ v / np.linalg.norm(u) / np.linalg.norm(v)
    s1, s2 = legs[0].uncertainty_m, legs[1].uncertainty_m
    assert path.uncertainty == pytest.approx(math.sqrt(s1**2 + s2**2 - s1 * s2 * cos), rel=1e-9)
    assert abs(cos) < 0.35  # the panel's corner is close to square in 3D
    assert path.uncertainty == pytest.approx(math.hypot(s1, s2), rel=0.1)


def test_straight_path_cancels_its_inner_ends():
    case = panel_case(1, width=W, height=H)
    a, b = np.array(case.clicks_px[0]), np.array(case.clicks_px[1])
    pts = [tuple(a), tuple((a + b) / 2), tuple(b)]
    path = measure_path(case.frame, pts)
    legs = _legs(case.frame, pts)
    # Collinear legs: the middle end moves one leg's length up and the other's down (cos = 1).
    assert path.uncertainty < math.hypot(*(m.uncertainty_m for m in legs))
    assert path.uncertainty == pytest.approx(path_sigma(legs))


def test_path_around_the_panel_matches_its_perimeter():
    case = panel_case(2, width=W, height=H)
    pts = list(case.clicks_px) + [case.clicks_px[0]]
    path = measure_path(case.frame, pts)
    # The truth of the closed outline from the true area and aspect of the clicked corners' legs.
    legs = path.parts
    assert len(legs) == 4
    assert legs[0] == pytest.approx(legs[2], rel=0.05) and legs[1] == pytest.approx(legs[3], rel=0.05)
    # Opposite sides' product is the panel's area.
    assert (legs[0] + legs[2]) / 2 * (legs[1] + legs[3]) / 2 == pytest.approx(case.area_m2, rel=0.05)


def test_path_of_one_click_is_refused():
    case = panel_case(0, width=W, height=H)
    with pytest.raises(MeasureError, match="at least 2"):
        measure_path(case.frame, case.clicks_px[:1])
