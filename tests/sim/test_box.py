"""Box dimensions on the simulator (sim.shapes box cases, 640x360): plain boxes at 1 m on a floor or a
table against the scene's own box geometry, cut boxes judged "check" or worse, and clicks that are no
box top (the floor itself) refused with a typed error."""

from __future__ import annotations

import numpy as np
import pytest

from measure import MeasureError
from measure.box import measure_box
from sim.shapes import box_case

W, H = 640, 360
SEEDS = tuple(range(8))


def _truth(case) -> np.ndarray:
    return np.array([case.length_m, case.width_m, case.height_m])


@pytest.fixture(scope="module")
def plain():
    """(case, answer) of plain boxes at 1 m."""
    out = []
    for seed in SEEDS:
        case = box_case(seed, range_m=1.0, variant="plain", width=W, height=H)
        out.append((case, measure_box(case.frame, case.click_px)))
    return out


def test_box_dimensions_match_the_scene(plain):
    err = np.array([100 * (np.array(b.dimensions_m) - _truth(c)) / _truth(c) for c, b in plain])
    # Heights from the two planes are tight; the top's sides from its outline are looser at 640 px.
    assert np.abs(err[:, 2]).max() <= 2.0, err[:, 2]
    assert np.median(np.abs(err[:, :2])) <= 4.0, err[:, :2]
    assert np.abs(err[:, :2]).max() <= 15.0, err[:, :2]


def test_box_answer_is_ordered_and_drawn_where_the_box_is(plain):
    for case, b in plain:
        assert b.length_m >= b.width_m > 0 and b.height_m > 0
        assert all(s > 0 for s in b.uncertainty_m)
        for (lo, hi), v in zip(b.intervals_m, b.dimensions_m):
            assert lo < v < hi
        # Each drawn corner lies within a few pixels of a true corner of the top face.
        true = np.array(case.corners_px)
        got = np.array(b.corners_px)
        gap = np.linalg.norm(got[:, None] - true[None], axis=2).min(axis=1)
        assert gap.max() <= 0.08 * np.linalg.norm(true[2] - true[0]), gap
        # The supporting plane's feet are one box height below the corners.
        drop = np.linalg.norm(np.subtract(b.corners_m, b.base_corners_m), axis=1)
        assert np.allclose(drop, b.height_m, rtol=0.05)


def test_box_cut_by_the_border_is_not_good():
    seen = 0
    for seed in range(6):
        case = box_case(seed, range_m=1.2, variant="cut", width=W, height=H)
        if case.visible > 0.9:  # this draw left the top inside the image
            continue
        try:
            b = measure_box(case.frame, case.click_px)
        except MeasureError:
            continue  # refused is as honest as "check"
        seen += 1
        assert b.quality in ("check", "unreliable"), (seed, b.quality, b.dimensions_m)
        assert b.reasons
    assert seen >= 2


def test_box_click_on_the_floor_is_refused():
    case = box_case(1, range_m=1.0, variant="plain", width=W, height=H)
    x, y = case.click_px
    # Below the box in the image: the floor in front of it.
    floor_px = (x, min(H - 5.0, max(p[1] for p in case.corners_px) + 0.3 * H))
    with pytest.raises(MeasureError, match="top face"):
        measure_box(case.frame, floor_px)
