"""Robust planes from registered disparity: a fit on given pixels, or grown from a click (docs/method.md Eq. 9-11).

A 3D plane seen by a pinhole camera is an affine function of the pixel in disparity (Eq. 9):
``d(x, y) = alpha x + beta y + gamma``, and its metric form is
``alpha fx X + beta fy Y + (alpha cx + beta cy + gamma + doffs) Z - fB = 0`` (Eq. 10). Stereo noise is
in d, so the plane is fit there, like the segment's disparity line (docs/decisions/shape-planes.md).

Steps of :func:`fit_plane`:

1. FAST-MCD (``measure.mcd``) on the points (x, y, d) of at most ``MCD_POINTS`` pixels: an exact fit
   when quantized disparity puts at least h points on one affine plane (a constant-disparity level
   included), otherwise the robust scatter's smallest axis. This start survives up to 50 % outliers
   (contention, edge bleeding, stray matches).
2. Tukey bisquare IRLS of Eq. 9 on every pixel, with the scale floored at the disparity quantum / sqrt(12)
   (the MAD is zero on quantized data) and at ``MIN_SIGMA_PX``; inliers within ``INLIER_SIGMAS`` scales.
3. Covariance of (alpha, beta, gamma): s² (A^T A)^-1 over the inliers, inflated by the residuals'
   spatial correlation (Eq. 11: the product of 1 + 2 sum of lag correlations along x and along y),
   plus the rounding error shared by the pixels of each quantized level.

:func:`grow_plane` starts from a window around a click and grows the connected inlier region over
one surface in an enlarging region of interest, refitting as it grows. Units: px and px of
disparity; metric outputs in metres (camera frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from measure.mcd import fast_mcd
from measure.robust_range import median
from measure.types import Frame, MeasureError

MCD_POINTS = 400
MAX_FIT_PIXELS = 3000
MIN_PLANE_PIXELS = 12
MIN_SIGMA_PX = 0.05
INLIER_SIGMAS = 3.0
TUKEY_C = 4.685
SEED_HALF_PX = 7
MAX_LAG = 6
CLOSE_PX = 7
GROW_FIT_PIXELS = 1000
CONVERGED_PX = 0.01
CLEAN_SHARE = 0.95
START_CONFIDENCE = 0.999
MIN_STARTS = 50
MAX_STARTS = 200
# One-sigma disparity offset common to a whole frame (px): the stereo calibration's drift with
# temperature and flex, a few tenths of a pixel on a consumer device. No fit over one frame sees it
# (every plane moves together), and it scales every length by about its share of the disparity
# (docs/decisions/shape-calibration-offset.md).
CALIBRATION_PX = 0.3
MERGED_SIGMAS = 4.0


@dataclass(frozen=True)
class Plane:
    """A plane fit in disparity (Eq. 9) with its covariance, and the camera to read it in metres.

    ``coeffs`` (alpha px/px, beta px/px, gamma px) and ``cov`` (3x3, their covariance); ``sigma_px`` the
    inliers' residual scale (px); ``n_points`` pixels offered, ``n_support`` inliers; ``quantum`` the
    disparity step (px, 0 = none); ``exact_fit`` whether FAST-MCD found an exact fit; ``support_px``
    (n_support x 2 int, x and y) the inlier pixels; ``fx, fy, cx, cy, fb, doffs`` the camera.
    """

    coeffs: tuple[float, float, float]
    cov: np.ndarray
    sigma_px: float
    n_points: int
    n_support: int
    quantum: float
    exact_fit: bool
    support_px: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    fb: float
    doffs: float

    def disparity_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Eq. 9: the plane's disparity (px) at pixels x, y (any shape)."""
        a, b, g = self.coeffs
        return a * np.asarray(x, float) + b * np.asarray(y, float) + g

    def points_at(self, x: np.ndarray, y: np.ndarray, coeffs: np.ndarray | None = None) -> np.ndarray:
        """3D points (..., 3, m) where the viewing rays of pixels x, y meet the plane (Eq. 2 with Eq. 9);
        ``coeffs`` (..., 3) evaluates other coefficients (the covariance propagation uses it)."""
        c = np.asarray(self.coeffs if coeffs is None else coeffs, float)
        x, y = np.asarray(x, float), np.asarray(y, float)
        d = c[..., 0] * x + c[..., 1] * y + c[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(d + self.doffs > 0, self.fb / (d + self.doffs), np.nan)
        return np.stack([(x - self.cx) * z / self.fx, (y - self.cy) * z / self.fy, z], axis=-1)

    def metric(self, coeffs: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """Eq. 10 as a unit normal n (towards the camera) and offset o: n . P + o = 0 (m)."""
        a, b, g = np.asarray(self.coeffs if coeffs is None else coeffs, float)
        n = np.array([a * self.fx, b * self.fy, a * self.cx + b * self.cy + g + self.doffs])
        k = float(np.linalg.norm(n))
        # -fB / |n| < 0: the camera centre (origin) is on the negative side; flip so it is positive.
        return -n / k, self.fb / k

    def coefficient_samples(self) -> np.ndarray:
        """Seven sigma points (7 x 3): the coefficients and +- one sigma along each principal axis of
        ``cov`` scaled by sqrt(3), whose spread propagates ``cov`` through any function (unscented)."""
        vals, vecs = np.linalg.eigh(self.cov)
        axes = vecs * np.sqrt(np.clip(vals, 0.0, None) * 3.0)
        c = np.asarray(self.coeffs, float)
        return np.vstack([c, c + axes.T, c - axes.T])


def parallel_plane(plane: Plane, offset_m: float) -> Plane:
    """``plane`` moved along its normal to the metric offset ``offset_m`` (Eq. 10 solved for Eq. 9's
    coefficients; the covariance stays): a start for fitting a parallel surface."""
    n = plane.metric()[0]
    k = plane.fb / offset_m
    a, b = -k * n[0] / plane.fx, -k * n[1] / plane.fy
    return replace(plane, coeffs=(float(a), float(b), float(-k * n[2] - a * plane.cx - b * plane.cy - plane.doffs)))


def offset_plane(plane: Plane, delta_px: float = CALIBRATION_PX) -> Plane:
    """``plane`` as a disparity offset of ``delta_px`` common to the frame would show it (gamma + delta):
    a shape measured on offset planes, less the one measured, is that offset's share of its error."""
    a, b, g = plane.coeffs
    return replace(plane, coeffs=(a, b, g + delta_px))


def joined_another(own: Plane, grown: Plane, x: float, y: float) -> bool:
    """Whether the plane of a click's own window ``own`` differs from the plane grown from it at the
    click (x, y px) by more than ``MERGED_SIGMAS`` of their combined disparity one-sigma (Eq. 11
    covariances): a neighbour's top a few centimetres higher or lower joined the grown face and
    tilted or shifted its plane."""
    g = np.array([x, y, 1.0])
    diff = float(own.disparity_at(x, y) - grown.disparity_at(x, y))
    return abs(diff) > MERGED_SIGMAS * math.sqrt(float(g @ own.cov @ g + g @ grown.cov @ g))


def sigma_of(samples: np.ndarray) -> np.ndarray:
    """One-sigma of a quantity evaluated at :meth:`Plane.coefficient_samples` (first axis: the 7 points)."""
    s = np.asarray(samples, float)
    return np.sqrt(((s[1:] - s[0]) ** 2).sum(axis=0) / 6.0)


def _quantum(d: np.ndarray) -> float:
    u = np.unique(d[: 4000])
    if u.size < 2:
        return 0.0
    step = float(np.diff(u).min())
    return step if step >= 1e-3 else 0.0


def _weighted_fit(x: np.ndarray, y: np.ndarray, d: np.ndarray, w: np.ndarray) -> np.ndarray:
    ax = np.stack([x, y, np.ones_like(x)], axis=1)
    aw = ax * w[:, None]
    return np.linalg.solve(aw.T @ ax + 1e-12 * np.eye(3), aw.T @ d)


def _start(x: np.ndarray, y: np.ndarray, d: np.ndarray, seed: int, floor: float) -> tuple[np.ndarray, bool]:
    """Step 1: the least-squares plane when ``CLEAN_SHARE`` of the pixels lie within ``INLIER_SIGMAS``
    robust scales (floored at ``floor``) of it (a window inside one face), else FAST-MCD on (x, y, d)
    of at most MCD_POINTS pixels; the plane as Eq. 9 coefficients and whether it is an exact fit."""
    ls = _weighted_fit(x, y, d, np.ones(len(x)))
    r = d - (ls[0] * x + ls[1] * y + ls[2])
    scale = max(floor, 1.4826 * float(median(np.abs(r - median(r)))))
    share = float(np.mean(np.abs(r) <= INLIER_SIGMAS * scale))
    if share >= CLEAN_SHARE:
        return ls, False
    # Random starts for a clean 4-point subset with probability START_CONFIDENCE at twice the
    # contamination the least-squares plane shows (it hides some), at most half.
    bad = min(0.5, 2.0 * (1.0 - share))
    starts = math.ceil(math.log(1.0 - START_CONFIDENCE) / math.log(1.0 - (1.0 - bad) ** 4))
    idx = np.arange(len(x))
    if len(idx) > MCD_POINTS:
        idx = np.sort(np.random.default_rng(seed).choice(len(x), MCD_POINTS, replace=False))
    x0, y0 = float(x[idx].mean()), float(y[idx].mean())
    pts = np.stack([x[idx] - x0, y[idx] - y0, d[idx]], axis=1)
    res = fast_mcd(pts, seed=seed, n_starts=int(np.clip(starts, MIN_STARTS, MAX_STARTS)))
    if res.exact_fit and res.fit_kind == "hyperplane":
        nx, ny, nd, off = res.plane
    else:
        vals, vecs = np.linalg.eigh(res.covariance)
        nx, ny, nd = vecs[:, 0]
        off = -float(vecs[:, 0] @ res.location)
    if abs(nd) < 1e-9:
        raise MeasureError("the clicked surface is seen edge-on (its disparity does not vary like a plane); click on a face that faces the camera")
    a, b = -nx / nd, -ny / nd
    return np.array([a, b, -off / nd - a * x0 - b * y0]), bool(res.exact_fit)


def _correlation_inflation(x: np.ndarray, y: np.ndarray, r: np.ndarray) -> float:
    """Eq. 11: (1 + 2 sum_l rho_x(l)) (1 + 2 sum_l rho_y(l)) of the residuals on their pixel grid."""
    x0, y0 = int(x.min()), int(y.min())
    shape = (int(y.max()) - y0 + 1, int(x.max()) - x0 + 1)
    grid, have = np.zeros(shape), np.zeros(shape, bool)  # zeros where no residual: they add nothing to a sum
    grid[y.astype(int) - y0, x.astype(int) - x0] = r
    have[y.astype(int) - y0, x.astype(int) - x0] = True
    var = float(np.mean(r**2)) if r.size else 0.0
    if not var > 0:
        return 1.0
    out = 1.0
    for axis in (0, 1):
        total = 0.0
        for lag in range(1, MAX_LAG + 1):
            if shape[axis] <= lag:
                break
            a, b = (grid[lag:], grid[:-lag]) if axis == 0 else (grid[:, lag:], grid[:, :-lag])
            pairs = int(np.count_nonzero(have[lag:] & have[:-lag] if axis == 0 else have[:, lag:] & have[:, :-lag]))
            if pairs < 10:
                break
            rho = float(np.einsum("ij,ij->", a, b)) / pairs / var
            if rho <= 0.05:
                break
            total += rho
        out *= 1.0 + 2.0 * total
    return out


def _grid_pixels(mask: np.ndarray, x0: int, y0: int, most: int = MAX_FIT_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (xs, ys) of ``mask`` (placed at x0, y0 in the frame) as :func:`fit_plane` thins them:
    every k-th row and column of the frame for at most ``most``, without listing them all first."""
    n = int(np.count_nonzero(mask))
    k = int(math.ceil(math.sqrt(n / most))) if n > most else 1
    ys, xs = np.nonzero(mask[(-y0) % k::k, (-x0) % k::k])
    return xs * k + (-x0) % k + x0, ys * k + (-y0) % k + y0


def fit_plane(frame: Frame, xs: np.ndarray, ys: np.ndarray, seed: int = 0, start: Plane | None = None) -> Plane:
    """Robust plane (Eq. 9-11) of the pixels ``xs``, ``ys`` (int arrays, px) of ``frame``.

    Pixels without valid disparity are dropped; more than ``MAX_FIT_PIXELS`` are thinned to a regular
    grid (every k-th row and column, so the residuals' correlation is still measured on a grid).
    ``start``: a plane of the same surface to begin the IRLS from instead of FAST-MCD (a region grown
    from it). Raises MeasureError with fewer than ``MIN_PLANE_PIXELS`` valid pixels or a surface seen edge-on.
    """
    xs = np.asarray(xs, np.int64).ravel()
    ys = np.asarray(ys, np.int64).ravel()
    k = 1
    if len(xs) > MAX_FIT_PIXELS:
        k = int(math.ceil(math.sqrt(len(xs) / MAX_FIT_PIXELS)))
        keep = (xs % k == 0) & (ys % k == 0)
        xs, ys = xs[keep], ys[keep]
    d_all = frame.disparity[ys, xs]
    ok = frame.valid(d_all)
    if ok.sum() < MIN_PLANE_PIXELS:
        raise MeasureError(
            f"only {int(ok.sum())} pixels with depth on the clicked surface ({MIN_PLANE_PIXELS} needed); "
            "click where the depth map has data"
        )
    x, y, d = xs[ok].astype(float), ys[ok].astype(float), d_all[ok].astype(float)
    q = _quantum(d)
    floor = max(MIN_SIGMA_PX, q / math.sqrt(12.0))
    coeffs, exact = (np.array(start.coeffs), start.exact_fit) if start is not None else _start(x, y, d, seed, floor)
    inl = np.ones(len(x), bool)
    reach = np.array([np.abs(x).max(), np.abs(y).max(), 1.0])
    for _ in range(6):
        r = d - (coeffs[0] * x + coeffs[1] * y + coeffs[2])
        near = np.abs(r[np.abs(r) <= INLIER_SIGMAS * 4 * floor + 1.0])
        # No pixel near the start (a start plane a neighbour's top pulled away): the floor scale stands.
        s = max(floor, 1.4826 * float(median(near))) if near.size else floor
        u = r / (TUKEY_C * s)
        w = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
        inl = np.abs(r) <= INLIER_SIGMAS * s
        if inl.sum() < MIN_PLANE_PIXELS:
            break
        new = _weighted_fit(x, y, d, w)
        moved = float(np.abs(new - coeffs) @ reach)  # the plane's largest change over the pixels (px)
        coeffs = new
        if moved < CONVERGED_PX:
            break
    r = d - (coeffs[0] * x + coeffs[1] * y + coeffs[2])
    inl = np.abs(r) <= INLIER_SIGMAS * s
    if inl.sum() < MIN_PLANE_PIXELS:
        raise MeasureError("the clicked pixels do not lie on one surface; click inside one flat face")
    xi, yi, ri = x[inl], y[inl], r[inl]
    sigma = max(floor, float(np.sqrt(np.mean(ri**2))))
    ax = np.stack([xi, yi, np.ones_like(xi)], axis=1)
    # The pixels' grid step (thinned here or by the caller, as ``_grid_pixels`` does): the residuals'
    # correlation is measured between neighbours on that grid.
    step = max(1, int(np.gcd.reduce(np.concatenate([xs - xs.min(), ys - ys.min()]))))
    cov = sigma * sigma * np.linalg.inv(ax.T @ ax) * _correlation_inflation(xi // step, yi // step, ri)
    if q > 0:  # the rounding shared by each level's pixels does not average out over them
        levels = max(1, np.unique(d[inl]).size)
        s2 = max(0.0, sigma * sigma - q * q / 12.0)
        cov[2, 2] += q * q / (12.0 * levels) * math.exp(-2.0 * math.pi**2 * s2 / (q * q))
    cam = frame.camera
    return Plane(
        coeffs=tuple(float(v) for v in coeffs),
        cov=cov,
        sigma_px=sigma,
        n_points=int(len(x)),
        n_support=int(inl.sum()),
        quantum=q,
        exact_fit=exact,
        support_px=np.stack([xi, yi], axis=1).astype(np.int64),
        fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy, fb=cam.fx * frame.baseline_m, doffs=float(frame.doffs),
    )


@dataclass(frozen=True)
class GrownPlane:
    """A plane grown over one surface: the fit, the surface's pixel mask (H x W bool, closed over
    outlier holes) and whether the surface reaches the image border."""

    plane: Plane
    mask: np.ndarray
    touches_border: bool


def inlier_mask(frame: Frame, plane: Plane, box: tuple[int, int, int, int]) -> np.ndarray:
    """Pixels of ``box`` (x0, y0, x1, y1, exclusive ends) whose disparity lies on ``plane`` (bool)."""
    x0, y0, x1, y1 = box
    a, b, g = plane.coeffs
    d = frame.disparity[y0:y1, x0:x1]
    tol = INLIER_SIGMAS * max(plane.sigma_px, plane.quantum * 0.75)
    with np.errstate(invalid="ignore"):
        return np.abs(d - (a * np.arange(x0, x1)[None, :] + (b * np.arange(y0, y1) + g)[:, None])) <= tol


def window_pixels(frame: Frame, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (xs, ys) of the (2 ``SEED_HALF_PX`` + 1)² window around pixel (x, y), cut by the image."""
    h, w = frame.shape
    cx, cy, r = int(round(x)), int(round(y)), SEED_HALF_PX
    yy, xx = np.mgrid[max(0, cy - r):min(h, cy + r + 1), max(0, cx - r):min(w, cx + r + 1)]
    return xx, yy


def grow_plane(frame: Frame, click: tuple[float, float], seed: int = 0, max_rounds: int = 6, window: Plane | None = None) -> GrownPlane:
    """The surface under ``click`` (x, y px): a robust plane of the window around it (``window``, when
    the caller has fit it already), grown over the connected pixels on that plane, refit and regrown in
    a region of interest that doubles while the surface reaches its edge. Raises MeasureError when the
    click has no surface with depth."""
    import cv2

    h, w = frame.shape
    cx, cy = int(round(click[0])), int(round(click[1]))
    r = SEED_HALF_PX
    plane = window if window is not None else fit_plane(frame, *window_pixels(frame, *click), seed)
    half = 4 * r
    touches = False
    for _ in range(max_rounds):
        box = (max(0, cx - half), max(0, cy - half), min(w, cx + half + 1), min(h, cy + half + 1))
        bx0, by0, bx1, by1 = box
        inl = inlier_mask(frame, plane, box).astype(np.uint8)
        # No closing: it would bridge the fattened halos of two boxes a few centimetres apart.
        _, labels = cv2.connectedComponents(inl, connectivity=8)
        near = labels[max(0, cy - by0 - 2):cy - by0 + 3, max(0, cx - bx0 - 2):cx - bx0 + 3]
        if not near.any():
            raise MeasureError("the click is not on a surface with depth; click inside a face where the depth map has data")
        lab = int(np.bincount(near[near > 0]).argmax())
        comp = labels == lab
        edges = ((comp[0].any(), by0 == 0), (comp[-1].any(), by1 == h), (comp[:, 0].any(), bx0 == 0),
                 (comp[:, -1].any(), bx1 == w))
        touches = any(hit and border for hit, border in edges)
        grown = not any(hit and not border for hit, border in edges)
        # While the region still grows its plane only steers the growth: a coarser grid of it will do.
        plane = fit_plane(frame, *_grid_pixels(comp, bx0, by0, MAX_FIT_PIXELS if grown else GROW_FIT_PIXELS), seed, start=plane)
        if grown:
            break
        half *= 2
    # Closing the component alone fills its outlier dents and holes without joining another surface.
    closed = cv2.morphologyEx(comp.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((CLOSE_PX, CLOSE_PX), np.uint8))
    contours, _ = cv2.findContours(closed, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    filled = np.zeros(comp.shape, np.uint8)
    cv2.drawContours(filled, contours, -1, 1, thickness=-1)  # the face with its outlier holes filled
    mask = np.zeros((h, w), bool)
    mask[by0:by1, bx0:bx1] = filled.astype(bool)
    return GrownPlane(plane, mask, touches)
