"""The robust method's end-model passes (measure.robust) hand each other every EndModels field."""

from __future__ import annotations

import numpy as np
import pytest

import measure.robust as robust
from measure import Frame, MeasureOptions, measure_distance

from factories import SMALL_B, SMALL_CAM, SMALL_F, SMALL_H, SMALL_W

WALL, FAR, NEAR = 15.0, 12.75, 22.5  # disparities (px): a wall at 2 m, a recess 15 % farther, a box in front
P1, P2 = (60.0, 120.0), (260.0, 120.0)


def _recess_and_contended_box(seed: int) -> Frame:
    """A wall with a small recess around P1 (10 px along the segment: shorter than a piece, so only the
    clean click window sees it) and a box in front around P2 whose image row through the segment is
    contended (uniform wrong matches of +-6 px), while the rows beside it show the box plainly."""
    rng = np.random.default_rng(seed)
    d = np.full((SMALL_H, SMALL_W), WALL)
    d[110:131, 51:70] = FAR
    d[100:141, 220:] = NEAR
    d += rng.normal(0.0, 0.1, d.shape)
    d[120, 220:] += rng.uniform(-6.0, 6.0, SMALL_W - 220)
    return Frame(np.zeros((SMALL_H, SMALL_W, 3), np.uint8), d.astype(np.float32), SMALL_CAM, SMALL_B)


def _point(p, disparity: float) -> np.ndarray:
    z = SMALL_F * SMALL_B / disparity
    return np.array([(p[0] - SMALL_CAM.cx) / SMALL_F * z, (p[1] - SMALL_CAM.cy) / SMALL_F * z, z])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_end_keeps_the_other_ends_piece(seed, monkeypatch):
    """_clean_ends moves P1 onto its recess; P2's piece flag (rough samples along the segment, no line of
    their own) must survive it so that _neighbourhood_ends finds the box beside the segment. When the
    flag was dropped (EndModels rebuilt without ``pieces``), P2 stayed on the wall: 1.493 m for 1.595 m,
    A = 93.6."""
    frame = _recess_and_contended_box(seed)
    seen = []
    clean = robust._clean_ends

    def spy(*args):
        out = clean(*args)
        seen.append((args[-1], out))
        return out

    monkeypatch.setattr(robust, "_clean_ends", spy)
    m = measure_distance(frame, P1, P2, MeasureOptions())
    truth = float(np.linalg.norm(_point(P2, NEAR) - _point(P1, FAR)))
    on_wall = float(np.linalg.norm(_point(P2, WALL) - _point(P1, FAR)))
    assert abs(on_wall - truth) > 0.06 * truth  # the dropped flag's answer is far off
    assert m.fit == "surfaces"
    assert m.distance_m == pytest.approx(truth, rel=0.005)
    assert abs(m.distance_m - truth) <= 2.0 * m.uncertainty_m
    # The case is the one meant: the click window corrected P1, and P2 kept its piece for the neighbourhood.
    (before, after), = seen
    assert not before.own[0] and after.own[0]
    assert before.pieces[1] > 0 and after.pieces[1] == before.pieces[1]
