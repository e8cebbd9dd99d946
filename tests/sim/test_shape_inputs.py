"""Bad input to the shape measurements gets a typed MeasureError that says what to change, never a
confident number: a click where the depth map has no data, outside the image, or options of the wrong type."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from measure import MeasureError
from measure.area import measure_area
from measure.box import measure_box
from measure.height import measure_height
from measure.path import measure_path
from sim.shapes import box_case

W, H = 640, 360


@pytest.fixture(scope="module")
def holed():
    """A box case whose depth has a 60x60 px hole (no data) around the top's click."""
    case = box_case(1, range_m=1.0, variant="plain", width=W, height=H)
    d = case.frame.disparity.copy()
    x, y = (int(v) for v in case.click_px)
    d[y - 30:y + 30, x - 30:x + 30] = np.nan
    return case, dataclasses.replace(case.frame, disparity=d)


def test_click_off_any_surface_is_refused(holed):
    case, frame = holed
    with pytest.raises(MeasureError, match="depth"):
        measure_box(frame, case.click_px)
    with pytest.raises(MeasureError, match="depth"):
        measure_height(frame, case.click_px)
    x, y = case.click_px
    with pytest.raises(MeasureError, match="depth"):
        measure_area(frame, [(x - 20, y - 20), (x + 20, y - 20), (x + 20, y + 20), (x - 20, y + 20)])


@pytest.mark.parametrize("click", [(-1.0, 10.0), (10.0, float(H)), (float("nan"), 5.0)])
def test_click_outside_the_image_is_refused(holed, click):
    case, _ = holed
    for call in (lambda: measure_box(case.frame, click), lambda: measure_height(case.frame, click),
                 lambda: measure_path(case.frame, [case.click_px, click])):
        with pytest.raises(MeasureError):
            call()


def test_options_of_the_wrong_type_are_refused(holed):
    case, _ = holed
    with pytest.raises(MeasureError, match="MeasureOptions"):
        measure_box(case.frame, case.click_px, options={"seed": 1})
