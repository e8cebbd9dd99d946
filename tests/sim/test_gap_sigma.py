"""A gap's uncertainty on the simulator: the doorway and the gap between two boxes, clicked at their
true edge pixels at 1.5-5 m. The 2σ interval covers the truth as often as it claims (not far more),
σ falls as the camera comes closer, and near answers are "good" (docs/decisions/gap-sigma.md)."""

from __future__ import annotations

import numpy as np
import pytest

import sim
from measure import MeasureOptions, measure_distance

DISTANCES = (1.5, 2.0, 2.5, 3.0, 4.0, 5.0)
SEEDS = tuple(range(12))  # 144 answers: a coverage of 95 % is then known to about +-4 % (Wilson)
CASES = (("doorway", "doorway"), ("boxes", "box-gap"))


@pytest.fixture(scope="module")
def answers():
    """(scene, distance, truth, answer with the default 1.5-px click sigma, answer with exact clicks)."""
    out = []
    for scene, target in CASES:
        for dist in DISTANCES:
            for seed in SEEDS:
                frame, truth, _ = sim.scenario(scene, target=target, distance_m=dist, seed=seed)
                m = measure_distance(frame, truth.p1_px, truth.p2_px)
                # The clicks are the true edge pixels: stated as exact, the sigma is the end surfaces' alone.
                exact = measure_distance(frame, truth.p1_px, truth.p2_px, MeasureOptions(click_px=0.0))
                out.append((scene, dist, truth.length_m, m, exact))
    return out


@pytest.mark.slow  # a coverage study over 144 rendered scenes: the full suite's, not the fast loop's
def test_two_sigma_covers_gaps_as_claimed(answers):
    """With the clicks stated exact (they are: the true edge pixels) the sigma is the end surfaces'. Its 2σ
    covers 85-98 % of the truths and its 1σ at most 80 % (nominal 68 %): the sigma scaled for real stereo's
    line ends (SIGMA_SCALE) covered 99 % / 82 % here, 85 % at 1σ on seeds 1000-1011."""
    ratio = np.array([abs(e.distance_m - g) / e.uncertainty_m for _, _, g, _, e in answers])
    assert 0.85 <= np.mean(ratio <= 2.0) <= 0.98, np.sort(ratio)[-12:]
    assert np.mean(ratio <= 1.0) <= 0.80, np.quantile(ratio, [0.5, 0.68, 0.8])
    # With a person's click sigma on these exact clicks, every gap answer is covered.
    assert all(abs(m.distance_m - g) <= 2 * m.uncertainty_m for _, _, g, m, _ in answers if m.gap_detected)


@pytest.mark.slow  # a coverage study over 144 rendered scenes: the full suite's, not the fast loop's
def test_sigma_falls_as_the_camera_comes_closer(answers):
    # Medians over distance bands, with the clicks' error a person's (1.5 px): both the click term and
    # the end surfaces' depth errors shrink with the depth.
    for scene, _ in CASES:
        def sig(lo: float, hi: float) -> float:
            return float(np.median([m.uncertainty_m for s, d, _, m, _ in answers if s == scene and lo <= d <= hi]))

        assert sig(1.5, 2.0) < sig(3.0, 3.0) < sig(5.0, 5.0), scene


@pytest.mark.slow  # a coverage study over 144 rendered scenes: the full suite's, not the fast loop's
def test_near_gaps_are_good_and_right(answers):
    near = [(g, m) for _, d, g, m, _ in answers if d <= 3.0]
    good = [(g, m) for g, m in near if m.quality == "good"]
    assert len(good) >= 0.8 * len(near), [m.reasons for _, m in near]
    assert all(m.gap_detected and abs(m.distance_m - g) <= 0.05 * g for g, m in good)


def test_sigma_falls_as_the_camera_comes_closer_on_integer_disparity():
    """A camera without subpixel disparity and little noise (1-px steps, 0.15 px): the ends' rounding is
    most of a doorway's sigma, and it is the ends' own, so it shrinks with their depth (it was the room's
    behind the door: 39-54 mm at 1.5-3 m, flat)."""
    sig = {}
    for dist in (1.5, 2.0, 3.0):
        for seed in (3, 4):
            frame, truth, _ = sim.scenario("doorway", target="doorway", distance_m=dist, seed=seed, quantization=1.0, noise_px=0.15,
                                           contention=0.1)
            m = measure_distance(frame, truth.p1_px, truth.p2_px, MeasureOptions(click_px=0.0))
            assert m.gap_detected and abs(m.distance_m - truth.length_m) <= 0.01 * truth.length_m
            sig.setdefault(dist, []).append(m.uncertainty_m)
    assert max(sig[1.5]) < min(sig[2.0]) and max(sig[2.0]) < min(sig[3.0]), sig
    assert max(sig[1.5]) < 0.01 * 0.9, sig  # under 1 % of the door's width at 1.5 m
