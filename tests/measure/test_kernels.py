"""The core's compiled kernels against the numpy formulations they replaced (the oracles below): the same
bits, for p = 1, 2, 3, singular and regular starts, and for rows of every length, with ties, of the
crease search's medians and MADs."""

from __future__ import annotations

import numpy as np
import pytest

from measure.cstep import det_adj, pairs
from measure.kernels import RIDGE, moments_det_lam, row_scales, start_coefficients, trimmed_crease_fits


def _numpy_coefficients(mean: np.ndarray, cov: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """The C-step's per-start arithmetic as it was written in numpy (ridge, closed-form inverse, terms)."""
    p = mean.shape[-1]
    ridge = RIDGE * np.maximum(cov.diagonal(axis1=-2, axis2=-1).sum(axis=-1), 1.0)
    singular = lam <= ridge
    if singular.any():
        cov = cov + (singular * ridge)[..., None, None] * np.eye(p)
    det, adj = det_adj(cov)
    inv = adj / det[..., None, None]
    j, k = pairs(p)
    quad = np.where(j == k, 1.0, 2.0) * inv[..., j, k]
    lin = -2.0 * np.einsum("...jk,...k->...j", inv, mean)
    const = -0.5 * np.einsum("...j,...j->...", lin, mean)
    return np.concatenate([const[..., None], lin, quad], axis=-1)


def _numpy_moments(sums: np.ndarray, p: int) -> tuple[np.ndarray, ...]:
    """Mean, covariance, determinant and det / trace(adj) from summed monomials, as written in numpy."""
    q = sums[..., 1:] / sums[..., :1]
    mean = q[..., :p]
    j, k = pairs(p)
    cov = np.empty(sums.shape[:-1] + (p, p))
    cov[..., j, k] = cov[..., k, j] = q[..., p:] - mean[..., j] * mean[..., k]
    if p == 1:
        return mean, cov, cov[..., 0, 0], cov[..., 0, 0]
    if p == 2:
        a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
        det, tr = a * d - b * b, d + a
    else:
        a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 0, 2]
        e, f, i = cov[..., 1, 1], cov[..., 1, 2], cov[..., 2, 2]
        m00 = e * i - f * f
        det = a * m00 + b * (c * f - b * i) + c * (b * f - c * e)
        tr = m00 + (a * i - c * c) + (a * e - b * b)
    return mean, cov, det, det / np.where(tr > 0, tr, np.inf)


def _numpy_scales(r: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Each row's max(1.4826 MAD, floor) and median by np.median."""
    med = np.median(r, axis=1)
    return np.maximum(1.4826 * np.median(np.abs(r - med[:, None]), axis=1), floor), med


def _starts(rng: np.random.Generator, p: int, s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random starts (quantized points, so some triples are collinear: singular) with their moments."""
    z = np.round(rng.normal(size=(s, p + 1, p)) * 2) / 2
    mono = np.concatenate([np.ones(z.shape[:-1] + (1,)), z, z[..., pairs(p)[0]] * z[..., pairs(p)[1]]], axis=-1)
    return _numpy_moments(mono.sum(axis=1)[None], p)[:2] + (mono.sum(axis=1)[None],)


@pytest.mark.parametrize("p", [1, 2, 3])
def test_c_step_arithmetic_is_the_numpy_arithmetic_bit_for_bit(p):
    rng = np.random.default_rng(p)
    mean, cov, sums = _starts(rng, p, 300)
    got = moments_det_lam(sums, p)
    for a, b in zip(got, _numpy_moments(sums, p)):
        np.testing.assert_array_equal(a, b)
    lam = got[3]
    assert (lam <= RIDGE).any() and (lam > RIDGE).any()  # both branches of the ridge
    np.testing.assert_array_equal(start_coefficients(mean, cov, lam), _numpy_coefficients(mean, cov, lam))
    regular = lam > RIDGE  # no start singular: no ridge on any
    m, c, l = mean[:, regular[0]], cov[:, regular[0]], lam[:, regular[0]]
    np.testing.assert_array_equal(start_coefficients(m, c, l), _numpy_coefficients(m, c, l))


@pytest.mark.parametrize("n", [20, 21, 127, 128, 129, 270, 383, 600, 1280, 1281])
def test_crease_medians_and_mads_are_the_order_statistics(n):
    """Residual rows of 48 candidates (quantized: many ties at the median and the MAD), short ones sorted
    by insertion and long ones narrowed by a sample first, are np.median's numbers to the bit; the
    one-row batches (the one line) the same."""
    rng = np.random.default_rng(n)
    t = np.sort(rng.uniform(0, 1.2 * n, n))
    d = np.round((30 + 0.01 * t + rng.normal(0, 0.3, n)) * 4) / 4
    bad = rng.random(n) < 0.35
    d[bad] *= rng.uniform(0.5, 1.5, bad.sum())
    t0 = np.concatenate([[np.inf], np.linspace(15, t[-1] - 15, 47)])
    beta = np.column_stack([rng.normal(30, 0.5, 48), rng.normal(0.01, 0.005, 48), rng.normal(0, 0.02, 48)])
    beta[3] = [0.0, 0.0, 0.0]  # residuals = the quantized data: ties everywhere
    r = d[None] - beta[:, :1]
    r -= beta[:, 1:2] * t[None]
    r -= beta[:, 2:3] * np.maximum(t[None] - t0[:, None], 0.0)
    want_s, want_med = _numpy_scales(r, 0.07)
    s, med = row_scales(t, d, t0, beta, 0.07)
    np.testing.assert_array_equal(med, want_med)
    np.testing.assert_array_equal(s, want_s)
    one = row_scales(t, d, t0[:1], beta[:1], 0.07)
    assert one[0][0] == want_s[0] and one[1][0] == want_med[0]


def test_crease_scale_of_a_constant_row_is_the_floor():
    t = np.arange(300.0)
    s, med = row_scales(t, np.full(300, 12.25), np.array([np.inf]), np.zeros((1, 3)), 0.07)
    assert med[0] == 12.25 and s[0] == 0.07


def _numpy_trimmed_fits(t: np.ndarray, d: np.ndarray, t0: np.ndarray, floor: float) -> np.ndarray:
    """The crease candidates' two least-squares passes as numpy wrote them: normal equations' sums by
    matrix products, LAPACK's solve, the trimmed samples from np.median's median and MAD."""
    H = np.maximum(t[None] - t0[:, None], 0.0)
    X = np.stack([np.ones_like(t), t], axis=1)

    def fit(w: np.ndarray) -> np.ndarray:
        A = np.empty((len(t0), 3, 3))
        A[:, :2, :2] = np.einsum("kn,ni,nj->kij", w, X, X)
        A[:, :2, 2] = A[:, 2, :2] = np.einsum("kn,ni,kn->ki", w, X, H)
        A[:, 2, 2] = np.einsum("kn,kn,kn->k", w, H, H)
        y = np.concatenate([w @ (X * d[:, None]), (w * H) @ d[:, None]], axis=1)
        return np.linalg.solve(A + 1e-9 * np.eye(3), y[..., None])[..., 0]

    beta = fit(np.ones_like(H))
    r = d[None] - beta[:, :1] - beta[:, 1:2] * t[None] - beta[:, 2:3] * H
    s, med = _numpy_scales(r, floor)
    return fit((np.abs(r - med[:, None]) <= 3.0 * s[:, None]).astype(float))


@pytest.mark.parametrize("n", [20, 270, 1280])
def test_trimmed_crease_fits_are_the_least_squares_ones(n):
    """Each candidate's second pass equals the numpy/LAPACK formulation to 1e-9 of the disparity (the
    normal equations in t up to 1300 px round differently in a loop and in BLAS), with the same trimmed
    samples, on a bent profile with 35 % wrong matches."""
    rng = np.random.default_rng(n)
    t = np.sort(rng.uniform(0, 1.2 * n, n))
    d = np.round((30 + 0.01 * t - 0.02 * np.maximum(t - 0.6 * t[-1], 0) + rng.normal(0, 0.3, n)) * 4) / 4
    bad = rng.random(n) < 0.35
    d[bad] *= rng.uniform(0.5, 1.5, bad.sum())
    t0 = np.concatenate([[np.inf], np.linspace(t[10], t[-11], 47)])  # at least 10 samples a side, as hinge_ends asks
    got, want = trimmed_crease_fits(t, d, t0, 0.07), _numpy_trimmed_fits(t, d, t0, 0.07)
    ends = np.stack([got[:, 0], got[:, 0] + got[:, 1] * t[-1] + got[:, 2] * np.maximum(t[-1] - t0, 0)])
    want_ends = np.stack([want[:, 0], want[:, 0] + want[:, 1] * t[-1] + want[:, 2] * np.maximum(t[-1] - t0, 0)])
    np.testing.assert_allclose(ends, want_ends, rtol=1e-9, atol=0)
    assert np.abs(want[0, 2]) < 1e-6 and got[0, 2] == 0.0  # the one line: no hinge


def _numpy_tukey_location(v: np.ndarray, c: float = 4.685, iterations: int = 30) -> tuple[float, float]:
    """Tukey's bisquare location and its standard error as written in numpy (measure.robust_range)."""
    from measure.robust_range import median, tukey_scale

    m, s = median(v), tukey_scale(v)
    if s == 0.0:
        return m, 0.0
    w = np.empty_like(v)
    for _ in range(iterations):
        np.subtract(v, m, out=w)
        w /= c * s
        np.multiply(w, w, out=w)
        np.subtract(1.0, w, out=w)
        np.maximum(w, 0.0, out=w)
        w *= w
        m_new = float((w * v).sum() / w.sum())
        if abs(m_new - m) <= 1e-12 * max(1.0, abs(m)):
            m = m_new
            break
        m = m_new
    inl = np.abs((v - m) / (c * s)) < 1.0
    spread = float(np.sqrt(((v[inl] - m) ** 2).mean())) if inl.any() else 0.0
    return m, (spread if spread > 0 else s) / np.sqrt(max(1, int(inl.sum())))


def test_pairwise_sum_is_numpys_sum_bit_for_bit():
    from measure.fit_kernels import _pairwise_sum

    rng = np.random.default_rng(11)
    for n in list(range(0, 300)) + [383, 384, 385, 1000, 1280, 5000]:
        a = rng.normal(size=n) * 10.0 ** rng.uniform(-6, 6, n)
        assert _pairwise_sum(a, n) == a.sum(), n


@pytest.mark.parametrize("n", [1, 2, 7, 8, 9, 40, 128, 129, 300, 700])
def test_tukey_location_is_the_numpy_loop_bit_for_bit(n):
    """The compiled bisquare iterations give numpy's location and standard error to the bit: on noisy
    rows with far outliers, on quantized rows (many ties, a zero MAD) and in single precision."""
    from measure.robust_range import tukey_location

    rng = np.random.default_rng(n)
    for _ in range(20):
        v = rng.normal(20.0, rng.uniform(0.01, 3.0), n)
        far = rng.random(n) < rng.uniform(0.0, 0.5)
        v[far] = rng.uniform(5.0, 60.0, int(far.sum()))
        for row in (v, np.round(v * 4) / 4, v.astype(np.float32)):
            assert tukey_location(row) == _numpy_tukey_location(np.asarray(row, dtype=np.float64))
