"""The compiled pieces of FAST-MCD, the robust line and the crease search (measure/mcd_kernels.py,
measure/fit_kernels.py ``robust_line``, measure/kernels.py ``crease_candidates``) against the numpy
formulations they replaced (the oracles below): the same order statistics and subsets, sums within
1e-12 relative (they are added in another order)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from measure.cstep import pairs
from measure.kernels import row_scales, trimmed_crease_fits
from measure.mcd import _axis_2x2, _canonical_sign
from measure.mcd_kernels import few_starts_step, keep_best, normalised, start_moments
from tests.measure.test_kernels import _numpy_coefficients, _numpy_moments


def _numpy_monomials(z: np.ndarray) -> np.ndarray:
    j, k = pairs(z.shape[1])
    return np.concatenate([np.ones((len(z), 1)), z, z[:, j] * z[:, k]], axis=1)


def _cloud(rng: np.random.Generator, n: int, p: int) -> np.ndarray:
    """Quantized points with 30 % far outliers (ties in every coordinate)."""
    x = np.round(rng.normal(size=(n, p)) * 4) / 4
    out = rng.random(n) < 0.3
    x[out] += rng.normal(0, 20, (int(out.sum()), p))
    return x


@pytest.mark.parametrize("p", [1, 2, 3])
@pytest.mark.parametrize("n", [7, 40, 271])
def test_normalised_is_the_median_mad_scaling(p, n):
    rng = np.random.default_rng(10 * p + n)
    x = _cloud(rng, n, p)
    center, s, z, mono, mono_t = normalised(x, 1e6)
    med = np.median(x, axis=0)
    np.testing.assert_array_equal(center, med)
    mad = 1.4826 * np.median(np.abs(x - med), axis=0)
    expected = max(float(np.sqrt((mad**2).sum())), float(np.abs(x - med).max()) / 1e6)
    assert s == pytest.approx(expected, rel=1e-15)
    np.testing.assert_allclose(z, (x - med) / s, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(mono, _numpy_monomials(z))
    np.testing.assert_array_equal(mono_t, mono.T)
    # Every MAD zero (more than half the points equal): the root of the summed variances.
    x[: n // 2 + 1] = 1.5
    _, s0, _, _, _ = normalised(x, 1e6)
    assert s0 == pytest.approx(max(float(np.sqrt(x.var(axis=0).sum())), float(np.abs(x - 1.5).max()) / 1e6), rel=1e-12)


@pytest.mark.parametrize("p", [1, 2, 3])
def test_start_moments_and_few_starts_step_are_the_numpy_c_step(p):
    rng = np.random.default_rng(p)
    n = 150
    h = (n + p + 1) // 2
    _, _, z, mono, mono_t = normalised(_cloud(rng, n, p), 1e6)
    draw = rng.integers(0, n, size=(2, 6 * (p + 1)))
    got = start_moments(mono, draw, p)
    sums = mono[draw].reshape(2, 6, p + 1, -1).sum(axis=2)
    for a, b in zip(got, _numpy_moments(sums, p)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    mean, cov, _, lam = got
    masks, mean2, cov2, det2, lam2 = few_starts_step(np.stack([mono, mono]), np.stack([mono_t, mono_t]), mean, cov, lam, h, p)
    d2 = np.maximum(_numpy_coefficients(mean, cov, lam) @ mono.T, 0.0)
    expected = d2 <= np.sort(d2, axis=-1)[..., h - 1 : h]
    assert np.array_equal(masks, expected) and (masks.sum(axis=-1) >= h).all()
    for a, b in zip((mean2, cov2, det2, lam2), _numpy_moments(expected.astype(np.float64) @ mono, p)):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


def test_keep_best_takes_the_lowest_determinants_first_on_ties():
    rng = np.random.default_rng(3)
    det = np.round(rng.uniform(0, 5, (3, 20)))  # ties
    mean, cov, lam = rng.normal(size=(3, 20, 2)), rng.normal(size=(3, 20, 2, 2)), rng.uniform(size=(3, 20))
    m, c, lm = keep_best(mean, cov, det, lam, 5)
    keep = np.argsort(det, axis=1, kind="stable")[:, :5]
    rows = np.arange(3)[:, None]
    np.testing.assert_array_equal(m, mean[rows, keep].reshape(1, -1, 2))
    np.testing.assert_array_equal(c, cov[rows, keep].reshape(1, -1, 2, 2))
    np.testing.assert_array_equal(lm, lam[rows, keep].reshape(1, -1))


def test_principal_axis_closed_form_is_the_eigenvector():
    rng = np.random.default_rng(4)
    for i in range(3000):
        m = rng.normal(size=(2, 2))
        c = m @ m.T * 10.0 ** rng.uniform(-8, 8)
        if i % 7 == 0:
            c[0, 1] = c[1, 0] = 0.0
        if i % 11 == 0:
            c = np.eye(2) * c[0, 0]
        expected = _canonical_sign(np.linalg.eigh(c)[1][:, -1])
        np.testing.assert_allclose(_canonical_sign(_axis_2x2(c[0, 0], c[0, 1], c[1, 1])), expected, atol=1e-12)


def _numpy_robust_line(t, d, support, alpha, beta, floor, alt, h, iterations):
    """The disparity line's steps after its start as measure/dline.py wrote them in numpy."""
    from measure.fit_kernels import bisquare_line

    r = d - (alpha + beta * t)
    scale = max(1.4826 * np.median(np.abs(r[support])), floor, 1e-6)
    alpha, beta, r = bisquare_line(t, d, alpha, beta, scale, iterations)
    if alt is not None:
        ra = d - (alt[0] + alt[1] * t)
        scale_a = max(1.4826 * np.median(np.partition(np.abs(ra), h - 1)[:h]), floor, 1e-6)
        tight = min(scale, scale_a)
        ends = np.array([t.min(), t.max()])
        if np.abs(alt[0] + alt[1] * ends - (alpha + beta * ends)).max() > 4.685 * tight:
            a2, b2, r2 = bisquare_line(t, d, alt[0], alt[1], scale_a, iterations)
            a2, b2, r2 = bisquare_line(t, d, a2, b2, tight, iterations)
            band = 4.685 * tight

            def lts(v):
                return float(np.partition(v * v, h - 1)[:h].sum())

            if lts(r2) < lts(r) and (np.abs(r2) < band).sum() > (np.abs(r) < band).sum():
                alpha, beta, r, scale = a2, b2, r2, tight
    sup = np.abs(r) < 4.685 * scale
    sigma = max(float(np.sqrt((r[sup] ** 2).mean())) if sup.any() else scale, floor)
    return alpha, beta, scale, sup, sigma, int(sup.sum()), float(t[sup].sum()), float(t[sup] @ t[sup])


@pytest.mark.parametrize("seed", range(12))
def test_robust_line_is_the_numpy_formulation(seed):
    from measure.fit_kernels import robust_line

    rng = np.random.default_rng(seed)
    n = int(rng.integers(30, 400))
    t = np.arange(n, dtype=np.float64)
    d = np.round((20 + 0.01 * t + rng.normal(0, 0.2, n)) * 16) / 16
    wrong = rng.random(n) < rng.uniform(0.1, 0.6)
    d[wrong] = rng.uniform(5, 40, int(wrong.sum()))  # wrong matches: the second start wins on some
    support = rng.random(n) < 0.7
    alpha, beta = 20.0 + rng.normal(0, 0.5), 0.01 + rng.normal(0, 0.005)
    alt = (20.0, 0.01) if seed % 3 else (float(np.median(d[:10])), 0.0)
    h = int(math.ceil(0.5 * n))
    got = robust_line(t, d, support, alpha, beta, 0.018, True, alt[0], alt[1], h, 50)
    expected = _numpy_robust_line(t, d, support, alpha, beta, 0.018, alt, h, 50)
    assert np.array_equal(got[3], expected[3]) and got[5] == expected[5]
    np.testing.assert_allclose(np.array(got[:3] + got[4:5] + got[6:]), np.array(expected[:3] + expected[4:5] + expected[6:]), rtol=1e-12)
    without = robust_line(t, d, support, alpha, beta, 0.018, False, 0.0, 0.0, h, 50)
    np.testing.assert_allclose(np.array(without[:3]), np.array(_numpy_robust_line(t, d, support, alpha, beta, 0.018, None, h, 50)[:3]),
                               rtol=1e-12)


@pytest.mark.parametrize("seed", range(8))
def test_crease_candidates_are_the_numpy_first_pass(seed):
    from measure.kernels import crease_candidates

    rng = np.random.default_rng(seed)
    n = int(rng.integers(25, 500))
    length = float(n) * rng.uniform(0.9, 1.6)
    t = np.sort(rng.uniform(0, length, n))
    kink = rng.uniform(0.2, 0.8) * length
    d = 30 + 0.01 * t + rng.uniform(0, 0.05) * np.maximum(t - kink, 0) + rng.normal(0, 0.1, n)
    t0s, b2, b1, s1, med1, parted = crease_candidates(t, d, length, 1 / 16, 0.018, 15.0, 10, 48, 0.1)
    cands = np.linspace(15.0, length - 15.0, 48)
    left = np.searchsorted(t, cands)
    cands = cands[(left >= 10) & (n - left >= 10)]
    np.testing.assert_array_equal(t0s, cands)
    creases = np.concatenate([[np.inf], cands])
    fits = trimmed_crease_fits(t, d, creases, 0.018)
    np.testing.assert_array_equal(b2, fits[1:])
    np.testing.assert_array_equal(b1, fits[0])
    scale, med = row_scales(t, d, creases[:1], fits[:1], 0.018)
    assert (s1, med1) == (scale[0], med[0])
    part = np.abs(fits[1:, 2]) * np.minimum(cands, length - cands)
    assert parted == bool((part > np.maximum(1 / 16, 0.1 * np.abs(fits[1:, 0] + fits[1:, 1] * cands))).any())


def test_full_data_stage_resumes_after_a_singular_start_without_exact_fit(monkeypatch):
    """Points within 1e-6 of a line but fewer than h of them within the exact-fit tolerance: the full-data
    stage hands its singular starts back, the exact-fit test finds no fit, the stage resumes from its
    state; the result is an ordinary MCD whose raw subset holds h points and whose estimates are that
    subset's and the support's moments."""
    import measure.compiled as kernels  # what measure.mcd calls (built ahead of time, or numba's)
    from measure.mcd import fast_mcd

    statuses = []
    stage = kernels.full_data_stage

    def spy(*args):
        out = stage(*args)
        statuses.append((out[0], args[-1]))
        return out

    monkeypatch.setattr(kernels, "full_data_stage", spy)
    rng = np.random.default_rng(0)
    n = 200
    t = rng.uniform(-1, 1, n)
    x = np.c_[t, 0.5 * t + rng.normal(0, 8e-7, n)]
    x[:20] += rng.normal(0, 1, (20, 2))
    res = fast_mcd(x, support_fraction=0.85, seed=0, max_iter=100)
    assert (1, False) in statuses and (0, True) in statuses  # handed back, then resumed to the end
    assert not res.exact_fit and res.raw_support.sum() >= res.h == 170
    np.testing.assert_allclose(res.raw_location, x[res.raw_support].mean(axis=0), rtol=0, atol=1e-12)
    np.testing.assert_allclose(res.location, x[res.support].mean(axis=0), rtol=0, atol=1e-12)
    assert not res.support[:20].any()  # the scattered points are outliers


@pytest.mark.parametrize("n", [1, 2, 3, 16, 17, 128, 129, 271])
def test_median_and_lag_one_correlation_are_numpys(n):
    from measure.robust_range import median
    from measure.uncertainty import correlation_inflation

    rng = np.random.default_rng(n)
    for v in (rng.normal(size=n), np.round(rng.normal(size=n) * 2) / 2, np.cumsum(rng.normal(size=n))):
        assert median(v) == np.median(v)  # the same order statistics: the same bits
        if n >= 4:
            r = v - v.mean()
            rho = min(0.9, max(0.0, float(r[:-1] @ r[1:]) / float(r @ r)))
            assert correlation_inflation(v) == pytest.approx(math.sqrt((1 + rho) / (1 - rho)), rel=1e-12)
    assert correlation_inflation(np.full(max(n, 4), 2.5)) == 1.0  # no spread: no correlation
