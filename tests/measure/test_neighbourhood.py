"""measure.neighbourhood: an end's surface from the image around its click, checked against known planes."""

from __future__ import annotations

import numpy as np

from measure.neighbourhood import end_plane


def _valid(v):
    return np.isfinite(v) & (v > 0)


def _plane(h=120, w=160):
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    return 20.0 + 0.02 * x + 0.05 * y


def test_plane_through_wrong_matches():
    rng = np.random.default_rng(3)
    d = _plane()
    wrong = rng.random(d.shape) < 0.3
    d[wrong] = rng.uniform(5.0, 60.0, int(wrong.sum()))
    d[rng.random(d.shape) < 0.1] = np.nan
    click, other = (80.0, 60.0), (80.0, 10.0)
    p = end_plane(d.astype(np.float32), _valid, click, other, quantum=1 / 16)
    assert p is not None
    assert abs(p.disparity - _plane()[60, 80]) < 0.1
    # towards the other click (up the image) the disparity falls by 0.05 px per px
    assert abs(p.slope + 0.05) < 0.01
    assert p.se > 0


def test_click_at_the_rim_sees_its_own_surface():
    d = _plane()
    d[:60, :] = 8.0  # a far wall above row 60; the click sits on the last row of the near surface
    p = end_plane(d.astype(np.float32), _valid, (80.0, 60.0), (80.0, 110.0), quantum=1 / 16)
    assert p is not None and abs(p.disparity - _plane()[60, 80]) < 0.1


def test_scattered_values_show_their_scatter():
    # Uniform wrong matches: either no plane or one whose scatter (px) gives it away; the caller
    # (measure.robust._neighbourhood_ends) rejects planes rougher than an own line may be.
    rng = np.random.default_rng(0)
    d = rng.uniform(5.0, 60.0, (120, 160)).astype(np.float32)
    p = end_plane(d, _valid, (80.0, 60.0), (80.0, 10.0), quantum=1 / 16)
    assert p is None or p.sigma > 10.0
    assert end_plane(np.full((120, 160), np.nan, np.float32), _valid, (80.0, 60.0), (80.0, 10.0), quantum=1 / 16) is None
