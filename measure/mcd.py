"""FAST-MCD (Rousseeuw & Van Driessen 1999) for small dimension (p = 1, 2, 3), vectorised numpy.

Minimum covariance determinant: among all h-subsets of the n points find the one whose
covariance has the smallest determinant; its mean and covariance are the robust location T
and scatter S used by docs/method.md steps 2-4 (h = 0.5 N tolerates up to 50 % outliers).

How it runs (inputs in any unit; tolerances are relative to a robust data scale):

1. Centre on the coordinate-wise median and divide by one robust scale ``s`` (root sum of
   squared MADs), so every tolerance below is dimensionless. ``s`` is at least 1e-6 of the
   farthest point's distance from the median (``_MAX_SPREAD``), whatever the outliers (a
   disparity of 1e-30 px is a point 1e31 m away): the normalised coordinates stay below 1e6,
   their squares, products and 3x3 determinants far inside float32 and float64 range, and the
   exact-fit tolerance (1e-6 s, at least 1e-12 of the extent) stays 1e4 times above float64's
   rounding of the farthest point, so a fitted subspace never loses its own points to rounding.
2. Random starts: ``n_starts`` (p+1)-point subsets drawn at once. For n > 600 the starts are
   split over up to five disjoint random subsamples of 300 points (R&VD section 3.3: the
   "nested" scheme), so a C-step costs O(starts x 300), not O(starts x n).
3. C-steps for all starts at once (``measure.cstep.c_step``: one matrix product of per-point
   monomials with per-start coefficients, closed-form 3x3 determinants). Two C-steps per start, keep
   the ten lowest determinants per subsample, two C-steps on the merged subsamples, then iterate
   the ten best on the full data to convergence and keep the lowest determinant (that stage and
   step 1 compiled, ``measure.mcd_kernels``).
4. Exact fit (R&VD section 3.4): when an h-subset covariance is singular (its smallest
   eigenvalue below ``(exact_tol * s)²``), at least h points lie on an affine subspace.
   The result then carries that subspace: a hyperplane ``a·x + d = 0`` (unit normal,
   coefficients (a, b, c, d) for p = 3), a line (p = 3, rank 1: collinear points), or a
   point (all support points equal), with the count of all points on it (distance
   <= ``exact_tol * s``). Starts that are singular but whose subspace holds fewer than h
   points of the full data are regularised and iterate on.
5. Consistency and reweighting: the raw covariance is multiplied by
   ``median(d²) / chi2_p(0.5)`` (R&VD eq. 1.3); points with ``d² <= chi2_p(0.975)`` form the
   reweighted support, whose mean and covariance are scaled by the Croux-Haesbroeck factor
   ``0.975 / P(chi2_{p+2} <= chi2_p(0.975))`` so that S estimates the covariance of the inliers.

Seeded with ``np.random.default_rng(seed)``: same input, same answer.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from measure.cstep import c_step, det_adj
from measure.robust_range import median
from measure.types import MeasureError

_SUBSAMPLE = 300  # R&VD nested scheme: subsample size
_MAX_GROUPS = 5
_MAX_SPREAD = 1e6  # normalised coordinates stay below this (see step 1 of the module docstring)
_MAX_ABS = 1e100  # coordinates beyond this are rejected: their squares would leave float64


@dataclass(frozen=True)
class McdResult:
    """FAST-MCD output, in the units of the input points.

    ``location``/``covariance`` are the reweighted estimates (the usual MCD output);
    ``raw_*`` the best h-subset's (covariance consistency-corrected). With an exact fit both
    are the mean and (singular) covariance of the points on the fitted subspace.
    ``distances`` are squared Mahalanobis distances to the reweighted estimate, or with an
    exact fit the squared orthogonal distances to the fitted subspace.
    """

    location: np.ndarray
    covariance: np.ndarray
    raw_location: np.ndarray
    raw_covariance: np.ndarray
    support: np.ndarray  # n bools: reweighted support, or the points on the exact fit
    raw_support: np.ndarray  # n bools: the best h-subset
    distances: np.ndarray
    h: int
    exact_fit: bool
    fit_kind: str  # "none" | "hyperplane" | "line" | "point"
    plane: tuple[float, ...] | None  # (a1..ap, d), unit normal, when fit_kind == "hyperplane"
    line_point: np.ndarray | None  # when the exact fit has rank 1 (a line in 2-D or 3-D)
    line_direction: np.ndarray | None
    n_on_fit: int
    scale: float  # the robust data scale the tolerances are relative to

    @property
    def n_support(self) -> int:
        return int(self.support.sum())

    def principal_axis(self) -> np.ndarray:
        """Unit eigenvector of the largest eigenvalue of ``covariance`` (sign: largest |component| > 0)."""
        if self.line_direction is not None:
            return self.line_direction
        if self.covariance.shape == (2, 2):
            return _canonical_sign(_axis_2x2(*(float(v) for v in self.covariance.ravel()[[0, 1, 3]])))
        _, vecs = np.linalg.eigh(self.covariance)
        return _canonical_sign(vecs[:, -1])


def _axis_2x2(a: float, b: float, d: float) -> np.ndarray:
    """Unit eigenvector of the larger eigenvalue of the symmetric [[a, b], [b, d]], closed form (a LAPACK
    call costs more than the arithmetic): lambda = (a + d) / 2 + hypot((a - d) / 2, b), the vector
    (lambda - d, b) or (b, lambda - a), whichever is longer; (0, 1) for a multiple of the identity
    (as LAPACK's last eigenvector)."""
    lam = 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    v = (lam - d, b) if a >= d else (b, lam - a)
    norm = math.hypot(*v)
    return np.array([v[0] / norm, v[1] / norm]) if norm > 0 else np.array([0.0, 1.0])


def _canonical_sign(v: np.ndarray) -> np.ndarray:
    return v if v[np.argmax(np.abs(v))] >= 0 else -v


def default_h(n: int, p: int, support_fraction: float | None) -> int:
    """Subset size: the maximal-breakdown ``(n + p + 1) // 2``, or ``ceil(f n)`` if larger."""
    h = (n + p + 1) // 2
    if support_fraction is not None:
        h = max(h, int(math.ceil(support_fraction * n)))
    return min(h, n)


def starts_for(p: int, contamination: float = 0.5, failure: float = 1e-9) -> int:
    """Random (p+1)-subsets needed so that, with probability ``1 - failure``, at least one holds
    no outlier when a fraction ``contamination`` of the points are outliers (R&VD section 3.1).

    A start is clean with probability (1 - eps)^(p+1), so m starts all miss with probability
    (1 - (1 - eps)^(p+1))^m. At eps = 0.5 and failure 1e-9: p = 2 needs 156, p = 3 needs 322
    (R&VD's fixed 500 covers p up to 3 with room to spare, and stays the default of
    :func:`fast_mcd`).
    """
    clean = (1.0 - contamination) ** (p + 1)
    return int(math.ceil(math.log(failure) / math.log1p(-clean)))


@dataclass(frozen=True)
class _Subspace:
    mean: np.ndarray  # normalised coordinates
    basis: np.ndarray  # p x r orthonormal directions spanned
    normals: np.ndarray  # p x (p - r)
    on: np.ndarray  # n bools


def _subspace_of(z: np.ndarray, subset: np.ndarray, tol: float) -> _Subspace:
    """The affine subspace spanned by ``z[subset]`` (two-pass, accurate), and all points on it."""
    pts = z[subset]
    mean = pts.mean(axis=0)
    cov = np.cov(pts - mean, rowvar=False, bias=True).reshape(z.shape[1], z.shape[1])
    vals, vecs = np.linalg.eigh(cov)
    rank = int((vals > tol * tol).sum())
    normals, basis = vecs[:, : z.shape[1] - rank], vecs[:, z.shape[1] - rank :]
    resid = (z - mean) @ normals
    on = np.sqrt((resid**2).sum(axis=1)) <= tol
    return _Subspace(mean, basis, normals, on)


def _exact_fit_result(x: np.ndarray, s: float, sub: _Subspace, h: int) -> McdResult:
    p = x.shape[1]
    pts = x[sub.on]
    loc = pts.mean(axis=0)
    cov = np.cov(pts - loc, rowvar=False, bias=True).reshape(p, p)
    rank = sub.basis.shape[1]
    plane = line_point = line_dir = None
    if rank == p - 1:
        kind = "hyperplane"
        normal = _canonical_sign(sub.normals[:, 0])
        plane = tuple(float(v) for v in normal) + (float(-normal @ loc),)
    else:
        kind = "point" if rank == 0 else "line"
    if rank == 1:
        line_point, line_dir = loc, _canonical_sign(sub.basis[:, 0])
    resid = (x - loc) @ sub.normals
    return McdResult(
        location=loc,
        covariance=cov,
        raw_location=loc,
        raw_covariance=cov,
        support=sub.on.copy(),
        raw_support=sub.on.copy(),
        distances=(resid**2).sum(axis=1),
        h=h,
        exact_fit=True,
        fit_kind=kind,
        plane=plane,
        line_point=line_point,
        line_direction=line_dir,
        n_on_fit=int(sub.on.sum()),
        scale=s,
    )


def fast_mcd(
    points: np.ndarray,
    *,
    support_fraction: float | None = None,
    h: int | None = None,
    n_starts: int = 500,
    n_best: int = 10,
    seed: int = 0,
    exact_tol: float = 1e-6,
    max_iter: int = 100,
) -> McdResult:
    """Robust location and scatter of ``points`` (n x p, p <= 3, any unit) by FAST-MCD.

    ``h`` (or ``support_fraction``: h = ceil(f n), at least the maximal-breakdown
    ``(n + p + 1) // 2``) is the subset size. With n <= p the points always span a lower
    dimensional subspace and the result is that exact fit. ``n_starts`` random (p+1)-subsets
    (see :func:`starts_for`), of which the ``n_best`` lowest determinants per subsample go on,
    and at most ``max_iter`` C-steps on the full data (R&VD: iterate to convergence; fewer
    leaves the best candidate as it stands, which suits a robust *start*, see measure/dline.py).
    Raises :class:`MeasureError` for empty, non-finite or too-high-dimensional input.
    """
    x = np.asarray(points, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[0] < 1 or not 1 <= x.shape[1] <= 3:
        raise MeasureError(f"fast_mcd needs an n x p array with n >= 1 and 1 <= p <= 3, got shape {x.shape}")
    largest = float(np.abs(x).max())  # NaN when any coordinate is
    if not math.isfinite(largest):
        raise MeasureError("fast_mcd got NaN or infinite coordinates; drop invalid points first")
    if largest > _MAX_ABS:
        raise MeasureError(f"fast_mcd got coordinates beyond {_MAX_ABS:g} in magnitude; rescale the points")
    n, p = x.shape
    if h is None:
        h = default_h(n, p, support_fraction)
    if not 1 <= h <= n:
        raise MeasureError(f"h={h} must lie in [1, n={n}]")
    if min(n_starts, n_best, max_iter) < 1:
        raise MeasureError(f"n_starts={n_starts}, n_best={n_best} and max_iter={max_iter} must each be at least 1")
    from measure.compiled import full_data_stage, keep_best, normalised, start_moments  # loaded on first use: `import measure` stays fast

    center, s, z, mono, mono_t = normalised(x, _MAX_SPREAD)
    tol = exact_tol

    if s == 0.0 or h == n or n <= p:
        sub = _subspace_of(z, np.ones(n, bool), tol)
        if sub.basis.shape[1] < p and sub.on.any():
            return _exact_fit_result(x, s, sub, h)
        return _finish(x, z, center, s, np.ones(n, bool), h)

    def exact(lam: np.ndarray, masks: np.ndarray, idx: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> McdResult | None:
        # Count, for every singular start at once, the points of all data on its hyperplane;
        # only the best one is rebuilt exactly (two-pass) and accepted if it holds >= h points.
        g, c = np.nonzero(lam <= tol * tol)
        _, vecs = np.linalg.eigh(cov[g, c])
        normals = vecs[:, :, 0]
        resid = z @ normals.T - np.einsum("kp,kp->k", mean[g, c], normals)
        counts = (np.abs(resid) <= 10 * tol).sum(axis=0)
        k = int(np.argmax(counts))
        if counts[k] < h:
            return None
        subset = np.zeros(n, bool)
        subset[idx[g[k]][masks[g[k], c[k]]]] = True
        sub = _subspace_of(z, subset, tol)
        if sub.basis.shape[1] == p or sub.on.sum() < h:
            return None
        return _exact_fit_result(x, s, sub, h)

    # Stage 1: random starts on up to five disjoint subsamples (all of the data when n is small).
    perm, draw = (_draws if isinstance(seed, int) else _draws.__wrapped__)(n, p, n_starts, seed)
    groups, m = perm.shape
    mean, cov, _, lam = start_moments(mono, draw, p)
    stages = [(perm, max(p + 1, int(math.ceil(h * m / n))))]
    if groups > 1:
        merged = perm.reshape(1, -1)
        stages.append((merged, max(p + 1, int(math.ceil(h * merged.shape[1] / n)))))
    # Stage 2: two C-steps per start; the n_best best per subsample go on to the merged subsamples, their
    # n_best best to all the data.
    for idx, hs in stages:
        if idx.shape[1] == n:
            sm, sm_t = mono[None], mono_t[None]
        else:
            # Subsample stages only rank candidates: single precision halves their cost; the full-data
            # stage (which decides exact fits) runs in double precision.
            sm = mono[idx].astype(np.float32)
            sm_t = np.ascontiguousarray(np.swapaxes(sm, 1, 2))
        for _ in range(2):
            masks, mean, cov, det, lam = c_step(sm, sm_t, mean, cov, lam, hs, p)
            if (lam <= tol * tol).any():
                found = exact(lam, masks, idx, mean, cov)
                if found is not None:
                    return _lowest_rank(found, x, z, s, h, seed, exact_tol)
        mean, cov, lam = keep_best(mean, cov, det, lam, n_best)
    # Stage 3: at most max_iter C-steps on all the data, compiled with their bookkeeping
    # (measure.mcd_kernels.full_data_stage); it hands singular starts back for the exact-fit test.
    state = (np.zeros((1, 0, n), bool), mean, cov, np.zeros((1, 0)), lam, np.zeros((1, 0, n), bool), math.inf, np.zeros(0, bool), 0)
    stepped = False
    while True:
        status, step, masks, mean, cov, det, lam, prev, best_det, best_mask = full_data_stage(
            mono[None], mono_t[None], *state, max_iter, h, p, tol * tol, stepped)
        if status == 0:
            break
        found = exact(lam, masks, np.arange(n)[None, :], mean, cov)
        if found is not None:
            return _lowest_rank(found, x, z, s, h, seed, exact_tol)
        state, stepped = (masks, mean, cov, det, lam, prev, best_det, best_mask, step), True
    return _finish(x, z, center, s, best_mask, h)


@functools.lru_cache(maxsize=512)
def _draws(n: int, p: int, n_starts: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Step 2's subsamples (groups x m point indices) and each group's starts' points (groups x
    per_group (p + 1)), drawn from ``np.random.default_rng(seed)``. They depend on the sizes and the
    seed only: kept for the next segment of the same length (read-only), as a person re-measures."""
    rng = np.random.default_rng(seed)
    if n > 2 * _SUBSAMPLE:
        groups = min(_MAX_GROUPS, n // _SUBSAMPLE)
        perm = rng.permutation(n)[: groups * _SUBSAMPLE].reshape(groups, _SUBSAMPLE)
    else:
        groups, perm = 1, np.arange(n)[None, :]
    per_group = max(1, n_starts // groups)
    draw = rng.integers(0, perm.shape[1], size=(groups, per_group * (p + 1)))
    if groups > 1:
        draw = np.take_along_axis(perm, draw, axis=1)
    perm.flags.writeable = draw.flags.writeable = False
    return perm, draw


def _lowest_rank(found: McdResult, x: np.ndarray, z: np.ndarray, s: float, h: int, seed: int, exact_tol: float) -> McdResult:
    """A hyperplane holding >= h points may hold a line (or point) with >= h points: report that.

    Searches within the hyperplane by FAST-MCD in its own (p-1)-dimensional coordinates.
    """
    p = x.shape[1]
    if found.fit_kind != "hyperplane" or p < 2:
        return found
    on = found.support
    normal = np.asarray(found.plane[:p])
    _, _, vt = np.linalg.svd(np.eye(p) - np.outer(normal, normal))
    basis = vt[: p - 1].T  # p x (p-1) orthonormal, spanning the plane
    inner = fast_mcd((x[on] - found.location) @ basis, h=h, seed=seed, exact_tol=exact_tol)
    if not inner.exact_fit:
        return found
    sub_on = np.zeros(len(x), bool)
    sub_on[np.flatnonzero(on)[inner.support]] = True
    sub = _subspace_of(z, sub_on, exact_tol)
    if sub.basis.shape[1] >= p - 1 or sub.on.sum() < h:
        return found
    return _exact_fit_result(x, s, sub, h)


@functools.lru_cache(maxsize=None)
def _chi2_constants(p: int) -> tuple[float, float, float]:
    """chi2_p(0.5), chi2_p(0.975) and the reweighted consistency factor 0.975 / P(chi2_{p+2} <= chi2_p(0.975))."""
    # chi2_k quantile = 2 gammaincinv(k/2, .), cdf = gammainc(k/2, ./2): scipy.special, because
    # importing scipy.stats costs ~1.5 s, paid by the first measurement or `import device`.
    from scipy.special import gammainc, gammaincinv

    q = 2.0 * float(gammaincinv(p / 2.0, 0.975))
    return 2.0 * float(gammaincinv(p / 2.0, 0.5)), q, 0.975 / float(gammainc((p + 2) / 2.0, q / 2.0))


def _mean_cov(z: np.ndarray, subset: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and (biased) covariance of ``z[subset]``, two-pass, and every point's offset from
    that mean. 0/1 weights in matrix products instead of boolean copies of the points: the
    same numbers to 1e-14, and :func:`_finish` takes 135 instead of 200-250 us at n = 1280."""
    w = subset.astype(np.float64)
    count = w.sum()
    mean = (w @ z) / count
    diff = z - mean
    return mean, (diff.T * w) @ diff / count, diff


def _d2(diff: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis lengths of the rows of ``diff`` under ``cov``."""
    det, adj = det_adj(cov)
    inv = adj / det if det > 0 else np.linalg.pinv(cov, hermitian=True)
    return np.einsum("ij,ij->i", diff @ inv, diff)


def _finish(x: np.ndarray, z: np.ndarray, center: np.ndarray, s: float, subset: np.ndarray, h: int) -> McdResult:
    """Consistency correction and reweighting (R&VD eq. 1.3 and section 1) of the best h-subset."""
    p = x.shape[1]
    med_q, q, reweight_factor = _chi2_constants(p)
    from measure.compiled import mcd_finish  # loaded on first use: `import measure` stays fast

    ok, raw_mean, raw_cov, support, mean, cov, d2 = mcd_finish(np.ascontiguousarray(z), np.ascontiguousarray(subset), med_q, q, reweight_factor)
    if ok:
        return _result(x, center, s, subset, h, raw_mean, raw_cov, support, mean, cov, d2)
    # A singular covariance: its pseudo-inverse in numpy.
    raw_mean, raw_cov, diff = _mean_cov(z, subset)
    d2 = _d2(diff, raw_cov)
    factor = median(d2) / med_q
    if factor > 0:
        raw_cov = raw_cov * factor
        d2 = d2 / factor
    support = d2 <= q
    mean, cov, diff = _mean_cov(z, support)
    cov = cov * reweight_factor
    return _result(x, center, s, subset, h, raw_mean, raw_cov, support, mean, cov, _d2(diff, cov))


def _result(x, center, s, subset, h, raw_mean, raw_cov, support, mean, cov, d2) -> McdResult:
    """The McdResult of :func:`_finish`'s estimates (normalised coordinates) in the input's units."""
    return McdResult(
        location=center + s * mean,
        covariance=(s * s) * cov,
        raw_location=center + s * raw_mean,
        raw_covariance=(s * s) * raw_cov,
        support=support,
        raw_support=subset.copy(),
        distances=d2,
        h=h,
        exact_fit=False,
        fit_kind="none",
        plane=None,
        line_point=None,
        line_direction=None,
        n_on_fit=0,
        scale=s,
    )
