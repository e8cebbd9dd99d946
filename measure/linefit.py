"""The robust model of the 3D points along the segment (docs/method.md steps 2-4).

FAST-MCD (``measure.mcd``) on the valid samples' 3D points (metres) gives either a robust
line (location T, first principal axis v0), or an exact fit: a plane holding at least h
points. The exact fit is classified:

- ``constant-depth``: a = b = 0, the plane Z = -d/c (quantized disparity: at least h
  samples share one disparity level);
- degenerate plane through the camera centre (|d| ~ 0): all samples lie on one image line
  (horizontal, vertical or 45-degree segments) and every 3D point, outliers included, lies
  on the plane of those viewing rays. It is not the object's surface. The line is then fit
  *within* that plane: FAST-MCD again in 2-D plane coordinates, which yields a robust line,
  or an exact line (a constant-depth line when it has no Z component);
- ``plane``: any other plane (end points are then projected onto it, Eq. 4-5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure.mcd import McdResult, fast_mcd

_DEGENERATE_D = 1e-7  # |d| / |T| below which a plane passes through the camera centre
_FLAT_AB = 1e-9  # |(a, b)| below which a plane's normal is the optical axis (a = b = 0)


@dataclass(frozen=True)
class LineModel:
    """Robust model of the segment's points (metres).

    kind "line": ``point`` + s ``direction``; "constant-depth": Z = ``depth``; "plane": ``plane``
    (a, b, c, d) with unit normal. ``support`` marks the samples in the fit; ``scatter`` is the
    robust 3x3 covariance of the support (m², consistency-corrected; singular for exact fits).
    """

    kind: str
    point: np.ndarray
    direction: np.ndarray | None
    plane: tuple[float, float, float, float] | None
    depth: float
    support: np.ndarray
    scatter: np.ndarray
    degenerate_plane: bool
    mcd: McdResult


def _from_mcd(res: McdResult, support: np.ndarray, degenerate: bool, top: McdResult) -> LineModel:
    if res.exact_fit and res.fit_kind == "hyperplane":
        a, b, c, d = res.plane
        if np.hypot(a, b) <= _FLAT_AB:
            return LineModel("constant-depth", res.location, None, None, -d / c, support, res.covariance, degenerate, top)
        return LineModel("plane", res.location, None, (a, b, c, d), float(res.location[2]), support, res.covariance, degenerate, top)
    if res.exact_fit and res.fit_kind == "point":
        return LineModel("constant-depth", res.location, None, None, float(res.location[2]), support, res.covariance, degenerate, top)
    v = res.principal_axis()
    if res.exact_fit and abs(v[2]) <= _FLAT_AB:
        return LineModel("constant-depth", res.location, v, None, float(res.location[2]), support, res.covariance, degenerate, top)
    return LineModel("line", res.location, v, None, float(res.location[2]), support, res.covariance, degenerate, top)


def fit_line(points: np.ndarray, support_fraction: float, seed: int) -> LineModel:
    """Robust line / exact-fit model of ``points`` (n x 3, metres, camera frame), docs/method.md steps 2-4."""
    res = fast_mcd(points, support_fraction=support_fraction, seed=seed)
    if not (res.exact_fit and res.fit_kind == "hyperplane"):
        return _from_mcd(res, res.support, False, res)
    a, b, c, d = res.plane
    if abs(d) > _DEGENERATE_D * float(np.linalg.norm(res.location)):
        return _from_mcd(res, res.support, False, res)
    # The plane of one image line's viewing rays: fit the line inside that plane. Every sample goes in,
    # projected onto it, not only the exact fit's h: a segment that steps over two pixel rows puts about
    # half its samples on each row's plane, and the half on one plane alone, at two disparity levels,
    # gave a line along Z (A 24 on a 0.84 m poster, sim paper profile). The other row's samples lie one
    # pixel's angle off the plane, which the projection removes at a cost of that pixel in position.
    normal = np.array([a, b, c])
    _, _, vt = np.linalg.svd(np.eye(3) - np.outer(normal, normal))
    basis = vt[:2].T  # 3 x 2 orthonormal, spanning the plane
    origin = res.location
    inner = fast_mcd((points - origin) @ basis, h=res.h, seed=seed)
    support = inner.support.copy()
    loc3 = origin + basis @ inner.location
    cov3 = basis @ inner.covariance @ basis.T
    if inner.exact_fit and inner.fit_kind == "point":
        return LineModel("constant-depth", loc3, None, None, float(loc3[2]), support, cov3, True, res)
    v3 = basis @ inner.principal_axis()
    v3 = v3 if v3[np.argmax(np.abs(v3))] >= 0 else -v3
    kind = "constant-depth" if inner.exact_fit and abs(v3[2]) <= _FLAT_AB else "line"
    return LineModel(kind, loc3, v3, None, float(loc3[2]), support, cov3, True, res)
