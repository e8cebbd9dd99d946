"""``measure.weak_stretches``: where along a segment the matcher's confidence is below the verdict's
threshold, as fractions of the segment (0 = p1, 1 = p2), on confidence maps built to the pixel."""

from __future__ import annotations

import numpy as np
import pytest

from measure import weak_stretches
from measure.confidence import LOW_CONFIDENCE, WEAK_WINDOW_PX

H, W = 40, 101


def flat(value: float) -> np.ndarray:
    return np.full((H, W), value, np.float32)


def test_no_map_or_full_support_has_no_weak_stretch():
    assert weak_stretches(None, (0, 20), (100, 20)).shape == (0, 2)
    assert weak_stretches(flat(1.0), (0, 20), (100, 20)).shape == (0, 2)


def test_the_threshold_is_the_verdicts():
    just_below, at = flat(LOW_CONFIDENCE - 0.01), flat(LOW_CONFIDENCE)
    assert weak_stretches(just_below, (0, 20), (100, 20)).tolist() == [[0.0, 1.0]]
    assert weak_stretches(at, (0, 20), (100, 20)).shape == (0, 2)


def test_a_weak_block_is_placed_along_the_segment_in_both_directions():
    c = flat(1.0)
    c[:, 60:81] = 0.0  # columns 60..80 of a segment over columns 0..100: fractions 0.6..0.8
    w = weak_stretches(c, (0, 20), (100, 20))
    assert w.shape == (1, 2)
    # the 5-pixel mean crosses 0.5 at the block's edges: within half the window of 0.595 and 0.805
    assert w[0] == pytest.approx([0.595, 0.805], abs=(WEAK_WINDOW_PX // 2 + 0.5) / 100)
    back = weak_stretches(c, (100, 20), (0, 20))
    assert back[0] == pytest.approx(1.0 - w[0][::-1], abs=1e-9)  # the same pixels seen from the other end


def test_vertical_and_diagonal_segments_read_the_pixels_they_cross():
    c = flat(1.0)
    c[20:, :] = 0.1  # the lower half is weak
    v = weak_stretches(c, (50, 0), (50, 39))
    assert v.shape == (1, 2) and v[0][1] == 1.0 and v[0][0] == pytest.approx(0.5, abs=0.05)
    d = weak_stretches(c, (0, 0), (39, 39))
    assert d.shape == (1, 2) and d[0][0] == pytest.approx(0.5, abs=0.05)


def test_one_dark_pixel_is_no_stretch_but_three_are():
    # the mean over WEAK_WINDOW_PX pixels: one unsupported pixel among supported ones is not a stretch
    one, three = flat(1.0), flat(1.0)
    one[:, 50] = 0.0
    three[:, 49:52] = 0.0
    assert weak_stretches(one, (0, 20), (100, 20)).shape == (0, 2)
    w = weak_stretches(three, (0, 20), (100, 20))
    assert w.shape == (1, 2) and w[0][0] < 0.5 < w[0][1] and w[0][1] - w[0][0] <= 0.04


def test_nan_counts_as_no_support_and_several_stretches_come_in_order():
    c = flat(1.0)
    c[:, 10:20] = np.nan
    c[:, 70:90] = 0.2
    w = weak_stretches(c, (0, 20), (100, 20))
    assert w.shape == (2, 2) and (np.diff(w.ravel()) > 0).all()
    assert w[:, 1] - w[:, 0] == pytest.approx([0.10, 0.20], abs=0.03)
