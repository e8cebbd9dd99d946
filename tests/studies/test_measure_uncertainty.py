"""The reported uncertainty against the truth: noisy frames and clicks that miss the intended pixels
by a Gaussian 1.5 px (the click error the uncertainty models), truth the intended segment's length.
The real-stereo coverage (Middlebury, SGBM) is checked in tests/studies/test_stress.py."""

from __future__ import annotations

import numpy as np
import pytest

from measure import MeasureOptions, measure_distance

from factories import plane_frame, true_length

NORMAL, K = np.array([0.3, -0.1, 1.0]), 3.0
P1, P2 = (30.0, 60.0), (290.0, 170.0)


@pytest.mark.slow
@pytest.mark.parametrize(
    "quantum, noise, outliers",
    [(None, 0.2, 0.0), (0.25, 0.2, 0.3), (None, 0.5, 0.3)],
    ids=["gaussian", "quantized+outliers", "noisy+outliers"],
)
def test_uncertainty_covers_the_truth(quantum, noise, outliers):
    g = true_length(plane_frame(NORMAL, K), NORMAL, K, P1, P2)
    rng = np.random.default_rng(7)
    err, sigma, inside = [], [], []
    for s in range(100):
        f = plane_frame(NORMAL, K, noise=noise, quantum=quantum, outliers=outliers, seed=1000 + s)
        c = np.rint(np.r_[P1, P2] + rng.normal(0.0, 1.5, 4))
        m = measure_distance(f, (c[0], c[1]), (c[2], c[3]), MeasureOptions(method="robust", gap_detection=False))
        err.append(abs(m.distance_m - g))
        sigma.append(m.uncertainty_m)
        inside.append(m.interval_m[0] <= g <= m.interval_m[1])
    err, sigma = np.array(err), np.array(sigma)
    assert (sigma > 0).all()
    assert 0.55 <= np.mean(err <= sigma) <= 0.95, np.mean(err <= sigma)
    assert np.mean(err <= 2 * sigma) >= 0.9
    assert np.mean(inside) >= 0.95
