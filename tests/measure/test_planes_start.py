"""measure.planes.fit_plane started from a plane far from every pixel (a neighbour's top pulled the
start away): the fit must answer from the data or refuse with MeasureError, never crash."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factories import flat_frame
from measure import MeasureError
from measure.planes import fit_plane


def test_a_start_plane_far_from_every_pixel_does_not_crash():
    frame = flat_frame(w=64, h=48, d=10.0)
    ys, xs = np.mgrid[8:40, 8:56]
    near = fit_plane(frame, xs, ys)
    assert near.coeffs[2] == pytest.approx(10.0, abs=1e-6)
    far = dataclasses.replace(near, coeffs=(0.0, 0.0, 40.0))  # 30 px from every pixel
    try:
        plane = fit_plane(frame, xs, ys, start=far)
    except MeasureError:
        return
    assert np.isfinite(plane.sigma_px) and plane.sigma_px > 0
