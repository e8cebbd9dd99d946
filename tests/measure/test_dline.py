"""The robust method's disparity line (measure/dline.py): its lighter FAST-MCD start must land the
bisquare fit where the converged R&VD run (500 starts, 10 best, C-steps to convergence) lands it."""

from __future__ import annotations

from unittest import mock

import numpy as np
import pytest

import measure.dline as dline
from measure.dline import fit_disparity_line
from measure.mcd import fast_mcd


def _converged(*args, n_best=10, max_iter=100, n_starts=500, **kwargs):
    return fast_mcd(*args, **kwargs)


def _segment(n: int, outliers: float, seed: int, quantum: float = 0.25):
    """Disparity along a tilted surface (px), rounded to ``quantum``. ``outliers`` of it are wrong:
    two thirds a background surface seen through runs of the segment (structured, the case a bad
    start gets wrong), one third scattered 20-50 % off."""
    rng = np.random.default_rng(seed)
    t = np.arange(n, dtype=np.float64)
    surface = 30.0 - 0.012 * t
    d = surface + rng.normal(0, 0.2, n)
    bad = np.zeros(n, bool)
    run = max(1, n // 20)
    while bad.sum() < 2 * outliers * n / 3 - run:
        start = rng.integers(0, n - run)
        bad[start : start + run] = True
    d[bad] = 0.5 * surface[bad] + rng.normal(0, 0.2, bad.sum())  # twice as far away
    scattered = rng.choice(np.flatnonzero(~bad), int(outliers * n) - bad.sum(), replace=False)
    d[scattered] *= 1.0 + rng.choice([-1.0, 1.0], scattered.size) * rng.uniform(0.2, 0.5, scattered.size)
    bad[scattered] = True
    return t, np.round(d / quantum) * quantum, ~bad


@pytest.mark.parametrize("n, outliers, seed", [(120, 0.3, 0), (640, 0.45, 1), (1280, 0.4, 2), (1500, 0.49, 3)])
def test_light_start_gives_the_converged_line(n, outliers, seed):
    t, d, good = _segment(n, outliers, seed)
    light = fit_disparity_line(t, d, 0.5, 0, 0.25)
    with mock.patch.object(dline, "fast_mcd", _converged):
        full = fit_disparity_line(t, d, 0.5, 0, 0.25)
    # Same line to far below its own standard error, at both ends of the segment.
    se = np.sqrt(np.diag(full.cov_at(0.0, float(n - 1))))
    for end in (0.0, float(n - 1)):
        assert abs(light.at(end) - full.at(end)) < 0.05 * se.max(), (end, light, full)
    # And the line is the inliers' line: 30 - 0.012 t within a few standard errors.
    assert abs(light.at(0.0) - 30.0) < 5 * se[0] + 0.02
    assert (light.support & ~good).sum() <= 0.05 * (~good).sum() + 1
