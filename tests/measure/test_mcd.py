"""FAST-MCD (measure/mcd.py) against scikit-learn's MinCovDet and on constructed exact fits."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from measure import MeasureError
from measure.mcd import default_h, fast_mcd


def _line_cloud(n: int, outlier_frac: float, seed: int, noise: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = rng.uniform(-1, 1, n)
    x = np.c_[0.8 * t, 0.3 * t + 0.1 * rng.normal(size=n), 4 + 0.2 * t] + rng.normal(0, noise, (n, 3))
    out = rng.random(n) < outlier_frac
    x[out] += rng.normal(0, 0.5, (out.sum(), 3)) + np.array([0.0, 0.0, -0.5])
    return x, out


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = abs(float(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(min(1.0, c))))


@pytest.mark.parametrize("n, frac, seed", [(60, 0.2, 0), (300, 0.4, 1), (1280, 0.4, 2)])
def test_matches_sklearn_mincovdet(n, frac, seed):
    from sklearn.covariance import MinCovDet

    x, out = _line_cloud(n, frac, seed)
    ours = fast_mcd(x, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = MinCovDet(random_state=seed).fit(x)
    assert not ours.exact_fit
    scale = np.sqrt(np.trace(ref.covariance_))
    assert np.linalg.norm(ours.location - ref.location_) < 0.05 * scale
    assert _angle_deg(ours.principal_axis(), np.linalg.eigh(ref.covariance_)[1][:, -1]) < 2.0
    # The support is the inliers: almost no outlier kept, almost every inlier kept.
    assert (ours.support & out).sum() <= 0.05 * out.sum() + 1
    assert (ours.support & ~out).sum() >= 0.9 * (~out).sum()


def test_deterministic_and_seed_invariant_on_clean_data():
    x, _ = _line_cloud(400, 0.3, 5)
    a, b = fast_mcd(x, seed=3), fast_mcd(x, seed=3)
    assert np.array_equal(a.location, b.location) and np.array_equal(a.support, b.support)
    c = fast_mcd(x, seed=11)
    assert _angle_deg(a.principal_axis(), c.principal_axis()) < 0.5


def test_exact_fit_constant_depth_plane():
    """Quantized disparity: 700 of 1000 points share one Z -> the plane Z = 4 (a = b = 0)."""
    x, _ = _line_cloud(1000, 0.0, 7)
    x[:700, 2] = 4.0
    res = fast_mcd(x)
    assert res.exact_fit and res.fit_kind == "hyperplane"
    a, b, c, d = res.plane
    assert abs(a) < 1e-9 and abs(b) < 1e-9 and c == pytest.approx(1.0) and d == pytest.approx(-4.0)
    assert res.n_on_fit == 700 and res.support.sum() == 700


def test_exact_fit_tilted_plane_coefficients_and_count():
    rng = np.random.default_rng(3)
    n = np.array([0.3, -0.5, 0.81])
    n /= np.linalg.norm(n)
    pts = rng.normal(size=(500, 3))
    pts -= np.outer(pts @ n - 2.0, n)  # on n . x = 2
    pts[:180] += rng.normal(0, 0.3, (180, 3))  # 320 on the plane, above h = 252
    res = fast_mcd(pts)
    assert res.exact_fit and res.fit_kind == "hyperplane" and res.n_on_fit == 320
    got = np.array(res.plane[:3])
    sign = np.sign(got @ n)
    assert np.allclose(sign * got, n, atol=1e-9) and sign * res.plane[3] == pytest.approx(-2.0)


def test_collinear_points_report_the_line():
    rng = np.random.default_rng(4)
    t = rng.uniform(-1, 1, 400)
    x = np.c_[t, 2 * t, 3 * t + 1]
    x[:100] += rng.normal(0, 1, (100, 3))
    res = fast_mcd(x)
    assert res.exact_fit and res.fit_kind == "line" and res.n_on_fit == 300
    assert _angle_deg(res.line_direction, np.array([1.0, 2.0, 3.0])) < 1e-6


def test_all_points_equal_and_tiny_inputs():
    res = fast_mcd(np.tile([1.0, 2.0, 3.0], (10, 1)))
    assert res.exact_fit and res.fit_kind == "point" and res.n_on_fit == 10
    assert np.allclose(res.location, [1, 2, 3])
    three = fast_mcd(np.array([[0, 0, 1.0], [1, 0, 1.0], [0, 1, 2.0]]))
    assert three.exact_fit and three.fit_kind == "hyperplane" and three.n_on_fit == 3
    two = fast_mcd(np.array([[0, 0, 1.0], [1, 1, 2.0]]))
    assert two.exact_fit and two.fit_kind == "line"


def test_one_dimensional():
    rng = np.random.default_rng(8)
    z = np.r_[rng.normal(5.0, 0.1, 70), rng.normal(9.0, 1.0, 30)]
    res = fast_mcd(z)
    assert res.location[0] == pytest.approx(5.0, abs=0.05)
    assert np.sqrt(res.covariance[0, 0]) == pytest.approx(0.1, rel=0.3)


@pytest.mark.parametrize(
    "bad, match",
    [(np.zeros((0, 3)), "n x p"), (np.zeros((5, 4)), "n x p"), (np.array([[1.0, np.nan, 2.0]] * 5), "NaN")],
)
def test_bad_input(bad, match):
    with pytest.raises(MeasureError, match=match):
        fast_mcd(bad)


@pytest.mark.parametrize("option", ["n_starts", "n_best", "max_iter"])
def test_search_sizes_must_be_positive(option):
    x, _ = _line_cloud(50, 0.2, 0)
    with pytest.raises(MeasureError, match=f"{option}=0"):
        fast_mcd(x, **{option: 0})


def test_default_h():
    assert default_h(100, 3, 0.5) == 52
    assert default_h(100, 3, 0.75) == 75
    assert default_h(3, 3, 0.5) == 3


def test_h_smallest_is_the_double_precision_selection():
    """The C-step's h smallest d² (selected on their 64-bit patterns) are the h smallest doubles, with any
    ties at the h-th: on rows whose values around the h-th differ only below single precision, on exact
    ties, on values beyond single precision's range, on values rounded a hair below zero (as 0) and on
    ordinary rows; the summed monomials (``masked_sums``) are those of that mask to 1e-12, and
    single-precision d² (the subsample stages) are selected as single-precision values."""
    from measure.cstep import _h_smallest
    from measure.mcd_kernels import masked_sums, normalised

    rng = np.random.default_rng(5)
    n, h = 200, 101
    mono = normalised(rng.normal(size=(n, 2)), 1e6)[3][None]
    mono_t = np.ascontiguousarray(np.swapaxes(mono, 1, 2))
    rows = [rng.uniform(0, 10, n) for _ in range(4)]
    near = rng.uniform(0, 10, n)
    near[rng.choice(n, 40, replace=False)] = 5.0 + rng.integers(-3, 4, 40) * 1e-12  # joined by single rounding
    tied = np.round(rng.uniform(0, 10, n), 1)  # exact ties at the h-th
    huge = rng.uniform(0, 10, n)
    huge[:150] = 1e300 * (1 + rng.uniform(0, 1e-9, 150))  # single precision: all infinite
    zeros = rng.uniform(0, 10, n)
    zeros[:120] = -rng.uniform(0, 1e-15, 120)  # on the start's support, rounded below zero: all tie at 0
    d2 = np.stack(rows + [near, tied, huge, zeros])[None]
    clamped = np.maximum(d2, 0.0)
    key, kth = _h_smallest(d2.copy(), h)
    mask, sums = np.empty(d2.shape, bool), np.full(d2.shape[:2] + (mono.shape[2],), np.nan)
    masked_sums(key, kth, mono_t, 0, mask, sums)
    expected = clamped <= np.sort(clamped, axis=-1)[..., h - 1 : h]
    assert np.array_equal(mask, expected)
    assert (mask.sum(axis=-1) >= h).all() and mask[0, 7].sum() == 120
    np.testing.assert_allclose(sums, expected.astype(np.float64) @ mono, rtol=1e-12, atol=1e-12)
    single = d2[:, :4].astype(np.float32)
    key32, kth32 = _h_smallest(single.copy(), h)
    mask32, sums32 = np.empty(single.shape, bool), np.empty(single.shape[:2] + (mono.shape[2],))
    masked_sums(key32, kth32, mono_t.astype(np.float32), 0, mask32, sums32)
    assert np.array_equal(mask32, single <= np.sort(single, axis=-1)[..., h - 1 : h])
    np.testing.assert_allclose(sums32, mask32.astype(np.float64) @ mono.astype(np.float32).astype(np.float64), rtol=1e-12, atol=1e-9)
