"""A box top's sides from its colour image (measure.box_edges, through measure.box.measure_box): on a
synthetic frame whose disparity is fattened into the background as block matching does, and whose top
carries a dark tape stripe parallel to two of its sides, the length and width are the image's edges,
not the fattened depth's nor the tape's; a grey image (no steps) leaves the depth's edges and says so."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from measure import Frame, measure_box
from measure.box_edges import FATTEN_REACH_PX
from tests.factories import camera

W, H, F, B = 400, 300, 400.0, 0.06
X0, X1, Y0, Y1 = 120, 280, 90, 210  # the top's pixels (exclusive ends): 160 x 120 px
D_TOP, D_BG = 30.0, 20.0  # disparity at the principal point (px): the top 0.8 m, the floor 1.2 m away
FATTEN = 4  # px the top's disparity bleeds into the background


def _frame(grey: bool = False, seed: int = 0) -> Frame:
    """The top (a rectangle facing the camera) over a parallel floor, its disparity fattened by
    ``FATTEN`` px; a bright top with a dark tape stripe 10-16 px inside its left side on a darker
    textured floor, or a flat grey image."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:H, 0:W]
    top = (xx >= X0) & (xx < X1) & (yy >= Y0) & (yy < Y1)
    halo = cv2.dilate(top.astype(np.uint8), np.ones((2 * FATTEN + 1,) * 2, np.uint8)).astype(bool)
    d = np.where(halo, D_TOP, D_BG) + rng.normal(0.0, 0.05, (H, W))
    if grey:
        img = np.full((H, W), 110.0)
    else:
        img = 60.0 + 8.0 * rng.standard_normal((H, W))
        img[top] = 150.0
        img[top & (xx >= X0 + 10) & (xx < X0 + 16)] = 95.0  # tape: an image step inside the face
        img += rng.normal(0.0, 3.0, (H, W))
    image = np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    return Frame(image, d.astype(np.float32), camera(W, H, F), B)


def _truth() -> tuple[float, float]:
    """The top's length and width (m): its outline, on the pixels' boundaries, at its depth."""
    z = F * B / D_TOP
    return (X1 - X0) * z / F, (Y1 - Y0) * z / F


def test_the_sides_are_the_image_steps_not_the_fattened_depth():
    box = measure_box(_frame(), ((X0 + X1) / 2, (Y0 + Y1) / 2))
    length, width = _truth()
    # The fattened depth alone is 2 x 4 px too long on each side: +5 % and +6.7 %.
    assert box.length_m == pytest.approx(length, rel=0.005)
    assert box.width_m == pytest.approx(width, rel=0.005)
    assert not any("colour image" in r for r in box.reasons)
    # Drawn where the top is: each corner within a pixel of the true one.
    true_px = np.array([[X0 - 0.5, Y0 - 0.5], [X1 - 0.5, Y0 - 0.5], [X1 - 0.5, Y1 - 0.5], [X0 - 0.5, Y1 - 0.5]])
    got = np.array(box.corners_px)
    assert np.linalg.norm(got[:, None] - true_px[None], axis=2).min(axis=1).max() <= 1.0


def test_without_image_steps_the_depth_edges_stand_and_the_answer_is_to_check():
    box = measure_box(_frame(grey=True), ((X0 + X1) / 2, (Y0 + Y1) / 2))
    length, width = _truth()
    assert box.quality == "check"
    assert any("no step in the colour image" in r for r in box.reasons)
    # The depth's edges moved in by half the fattening reach, that reach in their uncertainty.
    for value, truth, sigma in ((box.length_m, length, box.uncertainty_m[0]), (box.width_m, width, box.uncertainty_m[1])):
        foot = truth / (X1 - X0 if truth == length else Y1 - Y0)
        assert abs(value - truth) <= 2 * (FATTEN_REACH_PX / 2) * foot
        assert abs(value - truth) <= 2.5 * sigma
