"""The reported one-sigma uncertainty against the spread of 200 noisy repeats (within a factor 1.5)."""

from __future__ import annotations

import numpy as np
import pytest

from measure import MeasureOptions, measure_distance

from measure_synth import plane_frame, true_length

NORMAL, K = np.array([0.3, -0.1, 1.0]), 3.0
P1, P2 = (30.0, 60.0), (290.0, 170.0)


@pytest.mark.slow
@pytest.mark.parametrize(
    "quantum, noise, outliers",
    [(None, 0.2, 0.0), (0.25, 0.2, 0.3), (None, 0.5, 0.3)],
    ids=["gaussian", "quantized+outliers", "noisy+outliers"],
)
def test_uncertainty_matches_empirical_spread(quantum, noise, outliers):
    dist, sigma = [], []
    for s in range(200):
        f = plane_frame(NORMAL, K, noise=noise, quantum=quantum, outliers=outliers, seed=1000 + s)
        m = measure_distance(f, P1, P2, MeasureOptions(method="robust", gap_detection=False))
        dist.append(m.distance_m)
        sigma.append(m.uncertainty_m)
    spread = float(np.std(dist))
    ratio = float(np.median(sigma)) / spread
    assert 1 / 1.5 <= ratio <= 1.5, f"reported {np.median(sigma):.4f} m vs empirical {spread:.4f} m"
    # and the estimate is unbiased well within its spread
    assert abs(np.mean(dist) - true_length(f, NORMAL, K, P1, P2)) < 0.5 * spread
