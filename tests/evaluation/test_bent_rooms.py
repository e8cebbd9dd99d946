"""Bent segments: a wall, or a board standing in front of it, down to the floor (evaluation/bent_rooms.py).
The default method is on average at least as accurate as the click windows (basic) less half a point,
and never "good" when 10 % off."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.bent_rooms import room_cases, room_depth, run_bent_rooms, Room
from evaluation.stress import figures


@pytest.fixture(scope="module")
def records():
    return run_bent_rooms(range(500, 506))


def test_default_is_as_accurate_as_basic_and_not_confidently_wrong(records):
    f = figures(records)
    assert f["n"] >= 16 and f["answered"] == 1.0
    assert f["mean_A"] >= f["basic_mean_A"] - 0.5, f
    assert f["good_and_A_below_90"] == 0.0, f
    assert f["cov_2sigma"] >= 0.9, f


def test_rooms_are_what_they_say():
    # The wall is at the stated distance along the optical axis's floor-parallel direction, the floor
    # at the camera's height: back-projected points of each surface lie on their planes.
    room = Room("wall", 1.4, 10.0, 3.0, (0.5, 1.0))
    z, surface = room_depth(room)
    assert {0, 1} <= set(np.unique(surface))
    frame_cases = room_cases([3])
    assert all(c.truth_m > 0 for _, cases in frame_cases for c in cases)
    y, x = np.nonzero(surface == 1)
    a = np.radians(10.0)
    ry = (y - (z.shape[0] - 1) / 2) / 500.0
    zw = z[y, x] * (-ry * np.sin(a) + np.cos(a))  # world Z of wall points
    assert np.allclose(zw, 3.0)
