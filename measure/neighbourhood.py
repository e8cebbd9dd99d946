"""An end's surface from the image around its click: a robust plane of disparity over a half-window.

Used by the robust method (``measure.robust``) for an end whose samples along the segment form a
piece that disagrees with the global line (``measure.surfaces``: at least ``MIN_PIECE_PX`` px, offset
beyond 10 %) but too few, too rough or too contended for a line of their own: one image column or row
through a contended band can hold a handful of scattered values while the columns beside it show the
surface plainly. The plane d = a + b dx + c dy (px of disparity; dx, dy px from the click) is fit to
the valid pixels within ``RADIUS`` px of the click on the segment's side of it (pixels with
(p - click) . u >= 0, u towards the other click: a click at the rim of a surface sees that surface,
not what lies beyond it), by Tukey-bisquare IRLS from the median (a constant start: a majority surface
wins), scale floored at the quantum's q/sqrt(12). It answers only when it is a surface: at least
``MIN_PIXELS`` valid pixels, ``MIN_SUPPORT`` of them supported, its value at the click inside the
supported values' range; its residual scatter ``sigma`` is for the caller to judge against the
segment's own noise (scattered wrong matches give a plane as rough as their spread). Its standard error is counted as one sample per ``CORRELATION_PX`` x
``CORRELATION_PX`` block (stereo matching windows share errors between neighbours).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure.robust_range import TUKEY_C, median

RADIUS = 12  # px: half-window size around the click
MIN_PIXELS = 40  # valid pixels the half-window needs
MIN_SUPPORT = 0.5  # share of them the plane must support
CORRELATION_PX = 5  # one independent sample per block of this size


@dataclass(frozen=True)
class EndPlane:
    """Disparity (px) at the click from the plane, its standard error (px), its slope (px per px)
    towards the other click, and the plane's support."""

    disparity: float
    se: float
    slope: float
    sigma: float  # RMS residual of the supported pixels (px)
    n_support: int


def end_plane(disparity: np.ndarray, valid_of, click: tuple[float, float], other: tuple[float, float], quantum: float,
              radius: int = RADIUS, iterations: int = 20) -> EndPlane | None:
    """The robust plane of the module docstring at ``click`` (x, y px), on the side towards ``other``;
    None when the half-window shows no single surface. ``valid_of`` maps disparities to a valid mask."""
    h, w = disparity.shape
    xi, yi = int(round(click[0])), int(round(click[1]))
    x0, x1 = max(0, xi - radius), min(w, xi + radius + 1)
    y0, y1 = max(0, yi - radius), min(h, yi + radius + 1)
    box = disparity[y0:y1, x0:x1].astype(np.float64)
    dy, dx = np.mgrid[y0 - yi : y1 - yi, x0 - xi : x1 - xi]
    ux, uy = other[0] - click[0], other[1] - click[1]
    keep = valid_of(box) & (dx * ux + dy * uy >= 0)
    d = box[keep]
    if d.size < MIN_PIXELS:
        return None
    X = np.stack([np.ones(d.size), dx[keep].astype(np.float64), dy[keep].astype(np.float64)], axis=1)
    beta = np.array([median(d), 0.0, 0.0])
    r = d - X @ beta
    floor = quantum / math.sqrt(12.0)
    scale = max(1.4826 * median(np.abs(r)), floor, 1e-6)
    for _ in range(iterations):
        u = r / (TUKEY_C * scale)
        wgt = np.clip(1.0 - u * u, 0.0, None) ** 2
        A = X.T @ (X * wgt[:, None])
        if np.linalg.cond(A) > 1e10:
            return None
        new = np.linalg.solve(A, X.T @ (wgt * d))
        done = float(np.abs(new - beta).sum()) < 1e-6 * scale
        beta = new
        r = d - X @ beta
        if done:
            break
    support = np.abs(r) < TUKEY_C * scale
    ns = int(support.sum())
    if ns < MIN_SUPPORT * d.size:
        return None
    value = float(beta[0])
    ds = d[support]
    sig = max(float(np.sqrt((r[support] ** 2).mean())), floor)
    if not (ds.min() - 3.0 * sig <= value <= ds.max() + 3.0 * sig):
        return None
    independent = max(1.0, ns / CORRELATION_PX**2)
    n = math.hypot(ux, uy)
    return EndPlane(value, sig / math.sqrt(independent), float(beta[1] * ux + beta[2] * uy) / n, sig, ns)
