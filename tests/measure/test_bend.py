"""The crease search of measure.bend, vectorised over candidates, against the module docstring's rule
computed candidate by candidate in the plainest way (np.median, one weighted least squares each):
the same profiles flagged, the same crease, the same end values."""

from __future__ import annotations

import math

import numpy as np

from measure.bend import BEND_SIGMAS, CANDIDATES, MIN_INLIERS, MIN_PIECE_PX, MIN_PIECE_SAMPLES, PENALTY, hinge_ends
from measure.surfaces import DISAGREE_REL, LOCAL_ROUGHNESS
from measure.uncertainty import correlation_inflation


def _two_pass(X: np.ndarray, d: np.ndarray, floor: float):
    def wls(w):
        A = (X * w[:, None]).T @ X + 1e-9 * np.eye(X.shape[1])
        return np.linalg.solve(A, (X * w[:, None]).T @ d)

    def scale(r):
        return max(1.4826 * float(np.median(np.abs(r - np.median(r)))), floor)

    beta = wls(np.ones(d.size))
    r = d - X @ beta
    w = (np.abs(r - np.median(r)) <= 3.0 * scale(r)).astype(float)
    beta = wls(w)
    r = d - X @ beta
    return beta, r, scale(r)


def _plain_hinge(t, d, length, quantum, noise):
    n = t.size
    if length < 2 * MIN_PIECE_PX or n < 2 * MIN_PIECE_SAMPLES:
        return None
    floor = quantum / math.sqrt(12.0)
    ones = np.ones(n)
    _, r1, s1 = _two_pass(np.c_[ones, t], d, floor)
    best = None
    for t0 in np.linspace(MIN_PIECE_PX, length - MIN_PIECE_PX, CANDIDATES):
        left = int((t < t0).sum())
        if left < MIN_PIECE_SAMPLES or n - left < MIN_PIECE_SAMPLES:
            continue
        beta, r, s2 = _two_pass(np.c_[ones, t, np.maximum(t - t0, 0.0)], d, floor)
        if best is None or s2 < best[3]:
            best = (t0, beta, r, s2)
    if best is None:
        return None
    t0, (a, b, c), r, s2 = best
    n_eff = n / correlation_inflation(r) ** 2
    inl = np.abs(r - np.median(r)) <= 3.0 * s2
    if not n_eff * math.log(s1 * s1 / (s2 * s2)) > PENALTY * 2.0 * math.log(max(n_eff, 2.0)):
        return None
    if inl.mean() < MIN_INLIERS or s2 > LOCAL_ROUGHNESS * max(noise, floor):
        return None
    if not abs(c) * min(t0, length - t0) > max(BEND_SIGMAS * s2, quantum, DISAGREE_REL * abs(a + b * t0)):
        return None
    one, apart = np.abs(r1 - np.median(r1)) <= 3.0 * s2, np.abs(r1 - r) > 3.0 * s2
    if not (inl & apart).sum() > (one & apart).sum():
        return None
    ends = (a, a + b * length + c * (length - t0))
    for e, piece in ((0, inl & (t < t0)), (1, inl & (t >= t0))):
        if piece.sum() < MIN_PIECE_SAMPLES or not (d[piece].min() - quantum <= ends[e] <= d[piece].max() + quantum):
            return None
    return t0, ends


def test_vectorised_crease_search_is_the_plain_rule():
    rng = np.random.default_rng(7)
    flagged = 0
    for i in range(160):
        n = int(rng.integers(20, 400))
        length = float(n * rng.uniform(1.0, 1.5))
        t = np.sort(rng.uniform(0, length, n))
        bend = rng.normal(0, 0.08) if i % 2 else 0.0
        d = rng.uniform(5, 60) + rng.normal(0, 0.02) * t + bend * np.maximum(t - rng.uniform(0.2, 0.8) * length, 0)
        d = d + rng.normal(0, rng.uniform(0.02, 0.4), n)
        bad = rng.random(n) < rng.uniform(0, 0.3)
        d[bad] += rng.normal(0, 3, bad.sum())
        quantum = (0.25, 1 / 16, 1 / 8)[i % 3]
        d = np.round(d / quantum) * quantum
        noise = float(rng.uniform(0.05, 0.5))
        fast, plain = hinge_ends(t, d, length, quantum, noise), _plain_hinge(t, d, length, quantum, noise)
        assert (fast is None) == (plain is None), i
        if fast is not None:
            flagged += 1
            assert fast.t0 == plain[0]
            assert np.allclose(fast.d_end, plain[1], rtol=0, atol=1e-9)
    assert flagged >= 20  # bent profiles are among them: the comparison is not only of Nones


def _crease_with_junk(rng):
    """A crease at t0 (50-110 px of 160) bending by 0.08-0.12 px/px, 0.1-px noise, 10 % wrong matches over 2-15 px."""
    t = np.arange(0.0, 160.0)
    t0 = rng.uniform(50, 110)
    d = 9.0 + rng.choice([-1, 1]) * rng.uniform(0.08, 0.12) * np.maximum(t - t0, 0.0) + rng.normal(0, 0.1, t.size)
    bad = rng.random(t.size) < 0.1
    d[bad] = rng.uniform(2.0, 15.0, bad.sum())
    return t, np.round(d / 0.25) * 0.25, t0


def test_a_crease_among_scattered_wrong_matches_is_found_where_it_is():
    rng = np.random.default_rng(12)
    found = 0
    for _ in range(40):
        t, d, t0 = _crease_with_junk(rng)
        h = hinge_ends(t, d, 159.0, 0.25, 0.1)
        found += h is not None and abs(h.t0 - t0) < 12
    assert found >= 25


def test_median_and_mad_from_one_sort_are_the_partitioned_ones():
    """The crease search's row medians and MADs from one sort a row (the MAD as the smallest window of
    the sorted residuals) are np.median's numbers to the bit, on odd and even rows, quantized rows
    with many ties, constant rows and one-row batches."""
    from measure.bend import _scale

    rng = np.random.default_rng(3)
    for n in (20, 21, 268, 1280):
        for K in (1, 48):
            r = rng.normal(0, 1, (K, n)) * rng.uniform(0.01, 5, (K, 1)) + rng.normal(0, 3, (K, 1))
            r[: K // 2] = np.round(r[: K // 2] * 4) / 4  # quantized: ties at the median and at the MAD
            r[-1] = 2.5 if K > 1 else r[-1]
            s, med = _scale(r, 0.07)
            ref_med = np.median(r, axis=1)
            ref_mad = np.median(np.abs(r - ref_med[:, None]), axis=1)
            assert np.array_equal(med, ref_med)
            assert np.array_equal(s, np.maximum(1.4826 * ref_mad, 0.07))
