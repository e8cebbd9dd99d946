"""The plane an object stands on, found around it, and what the shape measurements share (m, px).

:func:`support_plane` takes the pixels of a ring around the object's surface mask (clear of the
contended band at its edge), fits a robust plane (``measure.planes.fit_plane``) and accepts it when
the object's top lies on the camera's side of it and in front of it along the top's viewing ray
(a front face of the object itself fails that test); otherwise the plane's inliers leave the ring
and the next plane is tried. With ``parallel_to``, only planes within ``PARALLEL_DEG`` of it count
(a box's top and the floor it stands on).

:func:`support_levels` finds the plane under a level top (a box's) among the levels parallel to it
in such a ring: the densest, unless it is not seen at the box's foot, where its side faces meet what
it stands on (``_foot_share``), and another level is (docs/decisions/box-support-level.md).
"""

from __future__ import annotations

import math

import numpy as np

from measure.planes import INLIER_SIGMAS, MIN_PLANE_PIXELS, Plane, fit_plane, parallel_plane
from measure.robust_range import median
from measure.sampling import check_point
from measure.types import Frame, MeasureError, MeasureOptions
from measure.verdict import judge

RING_GAP_PX = 8
RING_MIN_PX = 25
RING_PIXELS = 3000
PARALLEL_DEG = 12.0
MAX_CANDIDATES = 4
INTERVAL_Z = 1.96
LEVEL_BIN_M = 0.01
LEVEL_SHARE = 0.08
MAX_LEVEL_BINS = 4096
LEVEL_FIT_PIXELS = 500
FOOT_POINTS = 240
FOOT_TANGENT_PX = 3
FOOT_MIN = 0.3
FOOT_LEAST = 10
FOOT_STEPS_PX = (8, 16, 32)
RING_WIDEN = 2


def ring_pixels(mask: np.ndarray, gap_px: int, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (xs, ys) between ``gap_px`` and ``gap_px + width_px`` px around ``mask`` (H x W bool)."""
    import cv2

    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    reach = gap_px + width_px
    h, w = mask.shape
    y0, y1 = max(0, rows[0] - reach), min(h, rows[-1] + reach + 1)
    x0, x1 = max(0, cols[0] - reach), min(w, cols[-1] + reach + 1)
    m = mask[y0:y1, x0:x1].astype(np.uint8)
    inner = cv2.dilate(m, np.ones((2 * gap_px + 1,) * 2, np.uint8))
    # A regular grid of at most about RING_PIXELS ring pixels (every k-th row and column of the image):
    # the planes fit on them thin to fewer anyway. The gap is kept exactly (it keeps the contended band
    # at the edge out); the ring's outer reach only to the grid's step.
    k = int(math.ceil(math.sqrt(max(1, m.size - int(np.count_nonzero(inner))) / RING_PIXELS)))
    oy, ox = (-y0) % k, (-x0) % k
    reach_k = int(math.ceil(reach / k))
    outer = cv2.dilate(m[oy::k, ox::k], np.ones((2 * reach_k + 1,) * 2, np.uint8))
    ys, xs = np.nonzero(outer > inner[oy::k, ox::k])
    return xs * k + ox + x0, ys * k + oy + y0


def angle_deg(a: Plane, b: Plane) -> float:
    """Angle between two planes' normals (degrees)."""
    na, nb = a.metric()[0], b.metric()[0]
    return math.degrees(math.acos(min(1.0, abs(float(na @ nb)))))


def parallel_levels(frame: Frame, mask: np.ndarray, top: Plane, seed: int = 0,
                    min_drop_m: float = 0.0) -> tuple[Plane | None, bool]:
    """The plane and ``between`` of :func:`support_levels`."""
    return support_levels(frame, mask, top, seed, min_drop_m)[:2]


def support_levels(frame: Frame, mask: np.ndarray, top: Plane, seed: int = 0,
                   min_drop_m: float = 0.0) -> tuple[Plane | None, bool, float]:
    """The plane a box with top plane ``top`` stands on, whether another parallel level lies between
    them (a neighbour's top: the choice is ambiguous), and the share of the box's visible foot where
    that plane is seen (``_foot_share``), from the levels of a ring around the top (``_ring_levels``).
    When none of them is seen at the foot (``FOOT_MIN``) the ring widens, twice by ``RING_WIDEN``,
    until one is (beside a tall box on a table, a narrow ring sees only its side faces and the floor
    beyond the table's edge); failing that, the first ring's answer stands."""
    width = max(RING_MIN_PX, int(0.6 * math.sqrt(max(int(mask.sum()), 1))))
    line = _outline_px(mask, top)
    first = _ring_levels(frame, mask, top, line, seed, min_drop_m, width)
    if first[0] is None or first[2] >= FOOT_MIN:
        return first
    for _ in range(2):
        width *= RING_WIDEN
        got = _ring_levels(frame, mask, top, line, seed, min_drop_m, width)
        if got[0] is not None and got[2] >= FOOT_MIN:
            return got
    return first


def _ring_levels(frame: Frame, mask: np.ndarray, top: Plane, line: np.ndarray, seed: int, min_drop_m: float,
                 width: int) -> tuple[Plane | None, bool, float]:
    """:func:`support_levels` on a ring ``width`` px wide: among the ring's pixels, the dense levels below
    the top along its normal (a histogram of n . P + o in bins of ``LEVEL_BIN_M`` or two depth-noise
    scales, whichever is wider, holding at least ``LEVEL_SHARE`` of the ring; side faces spread over
    all levels, a floor or table is one), the densest whose robust plane is parallel to the top within
    ``PARALLEL_DEG``; if it is not seen at the foot, the level that is (``_foot_level``)."""
    xs, ys = ring_pixels(mask, RING_GAP_PX, width)
    d = frame.disparity[ys, xs]
    keep = frame.valid(d)
    xs, ys, d = xs[keep], ys[keep], d[keep].astype(float)
    if len(xs) < MIN_PLANE_PIXELS * 4:
        return None, False, 0.0
    z = top.fb / (d + top.doffs)
    pts = np.stack([(xs - top.cx) * z / top.fx, (ys - top.cy) * z / top.fy, z], axis=1)
    n, o = top.metric()
    below = -(pts @ n + o)  # metres below the top plane
    lo = max(min_drop_m, 0.0)
    sel = below > lo
    if sel.sum() < MIN_PLANE_PIXELS * 4:
        return None, False, 0.0
    # A level's spread along the normal is the ring's depth noise, Z² / fB times the disparity noise the
    # top shows (or the quantum's rounding): a coarse sensor's floor spans several centimetres.
    noise_px = max(top.sigma_px, top.quantum / math.sqrt(12.0))
    z_med = float(median(z))
    bin_m = max(LEVEL_BIN_M, 2.0 * z_med * z_med / top.fb * noise_px)
    noise_m = z * z / top.fb * noise_px  # each pixel's, along the normal
    idx = ((below[sel] - lo) / bin_m).astype(np.int64)
    hist = np.bincount(idx[idx < MAX_LEVEL_BINS])  # stray matches tens of metres away make no level
    # Two neighbouring bins together: a level straddling a bin edge still counts once.
    pair = hist[:-1] + hist[1:] if len(hist) > 1 else hist

    def whole_ring_plane(k: int) -> Plane | None:
        # The level's pixels, from the top moved down to them (its two bins' middle), then the whole ring
        # from there: inliers chosen by their residual to the plane, not by their noisy level, which
        # would truncate the noise on one side and bias the plane; a slab of side faces cut out by its
        # level fits a plane parallel to the top, but on the whole ring it turns away.
        level = np.flatnonzero((below >= lo + (k - 1) * bin_m) & (below <= lo + (k + 3) * bin_m))
        level = level[::max(1, len(level) // LEVEL_FIT_PIXELS)]  # it only steers the fit on the ring
        try:
            plane = fit_plane(frame, xs[level], ys[level], seed, start=parallel_plane(top, o + lo + (k + 1) * bin_m))
            plane = fit_plane(frame, xs, ys, seed, start=plane)
        except MeasureError:
            return None
        return plane if angle_deg(plane, top) <= PARALLEL_DEG and plane.n_support >= MIN_PLANE_PIXELS * 4 else None

    def slab_plane(k: int) -> Plane | None:
        # The ring's pixels within the level's slab (three noise scales or a bin) and clear of all that
        # stands above it (side faces, the box, a neighbour): on the whole ring a table's level turns
        # by 15-20 degrees into the side faces that meet it, or slides to the floor beyond it.
        in_pair = (below >= lo + k * bin_m) & (below < lo + (k + 2) * bin_m)
        drop = float(median(below[in_pair])) if in_pair.any() else lo + (k + 1) * bin_m
        keep = _clear_of(xs, ys, below < drop - INLIER_SIGMAS * noise_m)
        keep &= np.abs(below - drop) <= np.maximum(INLIER_SIGMAS * noise_m, bin_m)
        try:
            plane = fit_plane(frame, xs[keep], ys[keep], seed, start=parallel_plane(top, o + drop))
        except MeasureError:
            return None
        return plane if angle_deg(plane, top) <= PARALLEL_DEG and plane.n_support >= MIN_PLANE_PIXELS * 4 else None

    # First the densest level: runs of neighbouring dense pairs of bins (a level is a run of two or
    # three, side faces a long one), each run's densest pair, the densest run first.
    dense = np.flatnonzero(pair >= LEVEL_SHARE * len(xs))
    runs = np.split(dense, np.flatnonzero(np.diff(dense) > 1) + 1) if dense.size else []
    peaks = [int(r[np.argmax(pair[r])]) for r in runs]
    for i in np.argsort([-pair[p] for p in peaks], kind="stable")[:MAX_CANDIDATES]:
        plane = whole_ring_plane(peaks[i])
        if plane is None:
            continue
        foot = _foot_share(frame, line, top, plane)
        if foot < FOOT_MIN:
            seen = _foot_level(frame, xs, ys, line, top, hist, pair, slab_plane, seed)
            if seen is not None:
                return seen
        # A parallel level nearer below the top than the one chosen: a table under the box, or a
        # neighbour's top; which one the box stands on is not known from the ring alone.
        between = any(whole_ring_plane(peaks[j]) is not None for j in range(i))
        return _clear_of_sides(frame, xs, ys, plane, seed), between, foot
    return None, False, 0.0


def _foot_level(frame: Frame, xs: np.ndarray, ys: np.ndarray, line: np.ndarray, top: Plane, hist: np.ndarray,
                pair: np.ndarray, slab_plane, seed: int) -> tuple[Plane, bool, float] | None:
    """The level seen at the box's foot (``_foot_share`` at least ``FOOT_MIN``) when the densest is not:
    a table under a tall box, with the floor beyond its edge filling the ring; a table beside which a
    neighbour's top is the densest level. Each histogram peak (a bin no emptier than its neighbours,
    in its denser pair) is a candidate, two levels a few bins apart too; the one seen best at the
    foot is taken, the nearest of equals (docs/decisions/box-support-level.md). None when no level
    is seen at the foot."""
    padded = np.concatenate([[0], hist, [0]])
    tops = np.flatnonzero((padded[1:-1] >= padded[:-2]) & (padded[1:-1] >= padded[2:]) & (hist > 0))
    pairs = np.where(padded[tops + 2] >= padded[tops], tops, tops - 1).clip(0, len(pair) - 1)
    peaks = np.unique(pairs[pair[pairs] >= LEVEL_SHARE * len(xs)])  # nearest below the top first
    peaks = peaks[np.sort(np.argsort(-pair[peaks], kind="stable")[:MAX_CANDIDATES])]
    levels = [(int(k), slab_plane(int(k))) for k in peaks]
    levels = [(k, pl, _foot_share(frame, line, top, pl)) for k, pl in levels if pl is not None]
    if not levels or max(f for _, _, f in levels) < FOOT_MIN:
        return None
    i = int(np.argmax([f for _, _, f in levels]))
    return _clear_of_sides(frame, xs, ys, levels[i][1], seed), i > 0, levels[i][2]


def _outline_px(mask: np.ndarray, top: Plane) -> np.ndarray:
    """Points of the outer outline of the largest region of ``mask`` (about ``FOOT_POINTS``) on the near
    sides of the top on plane ``top``, those whose side face turns towards the camera: n x 4 float,
    x and y (px), the outline's outward unit normal in the image and on the top plane (3D, m)."""
    import cv2

    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return np.zeros((0, 7))
    y0, x0 = max(0, rows[0] - 1), max(0, cols[0] - 1)
    sub = mask[y0:rows[-1] + 2, x0:cols[-1] + 2].astype(np.uint8)
    contours, _ = cv2.findContours(sub, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(int(x0), int(y0)))
    full = max(contours, key=len).reshape(-1, 2).astype(float)
    idx = np.arange(0, len(full), max(1, len(full) // FOOT_POINTS))
    t = full[(idx + FOOT_TANGENT_PX) % len(full)] - full[(idx - FOOT_TANGENT_PX) % len(full)]
    line = full[idx]
    nrm = np.stack([t[:, 1], -t[:, 0]], axis=1)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-9)
    nrm *= np.where(np.einsum("ij,ij->i", line - full.mean(axis=0), nrm) < 0, -1.0, 1.0)[:, None]
    p = top.points_at(line[:, 0], line[:, 1])
    out = top.points_at(line[:, 0] + nrm[:, 0], line[:, 1] + nrm[:, 1]) - p  # outward on the top plane
    with np.errstate(invalid="ignore"):
        near = np.einsum("ij,ij->i", out, -p) > 0
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    return np.hstack([line, nrm, out])[near]


def _foot_share(frame: Frame, line: np.ndarray, top: Plane, level: Plane) -> float:
    """Share of the top's near outline points (``_outline_px``) whose foot on ``level`` (the point on the top
    plane moved along the top's normal onto ``level``), seen ``FOOT_STEPS_PX`` further out in the
    image, shows ``level``'s disparity: where a box's side faces meet what it stands on, that surface is seen
    just outside them (on the near sides; the far ones are hidden by the box)."""
    h, w = frame.shape
    if not len(line):
        return 0.0
    p = top.points_at(line[:, 0], line[:, 1])
    n = top.metric()[0]
    nl, ol = level.metric()
    along = (p @ nl + ol) / float(n @ nl)
    f = p - along[:, None] * n
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.stack([top.fx * f[:, 0] / f[:, 2] + top.cx, top.fy * f[:, 1] / f[:, 2] + top.cy], axis=1)
    if not np.isfinite(px).all():
        return 0.0
    # Several steps out: near the foot the level and the side face look alike (below).
    look = np.rint(np.concatenate([px + k * line[:, 2:4] for k in FOOT_STEPS_PX])).astype(np.int64)
    f, line = np.tile(f, (len(FOOT_STEPS_PX), 1)), np.tile(line, (len(FOOT_STEPS_PX), 1))
    ok = (look[:, 0] >= 0) & (look[:, 0] < w) & (look[:, 1] >= 0) & (look[:, 1] < h)
    look, f, out = look[ok], f[ok], line[ok, 4:]
    x, y = look[:, 0], look[:, 1]
    # The side face, the vertical plane through the foot, predicts the same disparity as a level a
    # few centimetres below the top there: such a point tells nothing about the level.
    ray = np.stack([(x - top.cx) / top.fx, (y - top.cy) / top.fy, np.ones(len(x))], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_side = np.einsum("ij,ij->i", out, f) / np.einsum("ij,ij->i", out, ray)
        d_side = top.fb / z_side - top.doffs
    d_level = level.disparity_at(x, y)
    tol = INLIER_SIGMAS * max(level.sigma_px, level.quantum * 0.75)
    obs = frame.disparity[y, x]
    telling = ~(np.abs(d_side - d_level) <= 2.0 * tol) & frame.valid(obs)
    if np.count_nonzero(telling) < FOOT_LEAST:
        return 0.0
    return float(np.mean(np.abs(obs[telling] - d_level[telling]) <= tol))


def _clear_of(xs: np.ndarray, ys: np.ndarray, above: np.ndarray) -> np.ndarray:
    """Which of the ring pixels (xs, ys, a regular grid) lie farther than ``RING_GAP_PX`` from any
    flagged ``above`` (bool); all of them when fewer than ``MIN_PLANE_PIXELS * 4`` would be left."""
    import cv2

    keep = np.ones(len(xs), bool)
    if above.any():
        step = max(1, int(np.gcd.reduce(np.concatenate([xs - xs.min(), ys - ys.min()]))))
        gx, gy = (xs - xs.min()) // step, (ys - ys.min()) // step
        grid = np.zeros((int(gy.max()) + 1, int(gx.max()) + 1), np.uint8)
        grid[gy[above], gx[above]] = 1
        reach = int(math.ceil(RING_GAP_PX / step))
        keep = ~cv2.dilate(grid, np.ones((2 * reach + 1,) * 2, np.uint8))[gy, gx].astype(bool)
        if np.count_nonzero(keep) < MIN_PLANE_PIXELS * 4:
            keep[:] = True
    return keep


def _clear_of_sides(frame: Frame, xs: np.ndarray, ys: np.ndarray, plane: Plane, seed: int) -> Plane:
    """``plane`` refit on the ring pixels (xs, ys, a regular grid) near it and farther than
    ``RING_GAP_PX`` from any that stand clearly above it: where an object's side face meets its floor, the face's first
    pixels lie within the floor's tolerance and lift the plane (a box's height comes out short)."""
    tol = INLIER_SIGMAS * max(plane.sigma_px, plane.quantum * 0.75)
    # A wider surface far below (the floor beyond a table) would draw the fit's scale and then the
    # plane down to it: only pixels within twice the tolerance of the plane take part.
    with np.errstate(invalid="ignore"):
        resid = frame.disparity[ys, xs] - plane.disparity_at(xs, ys)
        keep = _clear_of(xs, ys, resid > tol) & (np.abs(resid) <= 2.0 * tol)
    if np.count_nonzero(keep) < MIN_PLANE_PIXELS * 4:
        return plane
    try:
        return fit_plane(frame, xs[keep], ys[keep], seed, start=plane)
    except MeasureError:
        return plane


def parallel_support(frame: Frame, mask: np.ndarray, top: Plane, seed: int = 0, min_drop_m: float = 0.0) -> Plane | None:
    """The plane of :func:`parallel_levels` alone."""
    return parallel_levels(frame, mask, top, seed, min_drop_m)[0]


def support_plane(frame: Frame, mask: np.ndarray, top_m: np.ndarray, parallel_to: Plane | None = None,
                  seed: int = 0, min_drop_m: float = 0.0) -> Plane | None:
    """The plane under an object (see the module docstring) or None; ``top_m`` a 3D point of its top (m)."""
    area = int(mask.sum())
    width = max(RING_MIN_PX, int(0.6 * math.sqrt(max(area, 1))))
    xs, ys = ring_pixels(mask, RING_GAP_PX, width)
    keep = frame.valid(frame.disparity[ys, xs])
    xs, ys = xs[keep], ys[keep]
    for _ in range(MAX_CANDIDATES):
        if len(xs) < MIN_PLANE_PIXELS * 4:
            return None
        try:
            plane = fit_plane(frame, xs, ys, seed)
        except MeasureError:
            return None
        n, o = plane.metric()
        drop = float(n @ top_m + o)  # > 0: the top is on the camera's side of the plane
        ok = drop > max(min_drop_m, 0.0) and (parallel_to is None or angle_deg(plane, parallel_to) <= PARALLEL_DEG)
        if ok and plane.n_support >= MIN_PLANE_PIXELS * 4:
            return plane
        r = frame.disparity[ys, xs] - plane.disparity_at(xs, ys)
        off = ~(np.abs(r) <= INLIER_SIGMAS * max(plane.sigma_px, plane.quantum))
        xs, ys = xs[off], ys[off]
    return None


def cross2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the cross product of 2D vectors (..., 2): a_x b_y - a_y b_x (np.cross of 2-vectors is deprecated)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def polygon_mask(shape: tuple[int, int], vertices: np.ndarray, pad: int = 0) -> tuple[np.ndarray, int, int]:
    """Pixels inside the polygon of ``vertices`` (n x 2, x y px) as a bool mask of its bounding box
    widened by ``pad`` px (cut by the image of ``shape`` H x W), and that box's corner (x0, y0) in the image."""
    import cv2

    h, w = shape
    v = np.round(np.asarray(vertices, float)).astype(np.int64)
    x0, y0 = int(np.clip(v[:, 0].min() - pad, 0, w - 1)), int(np.clip(v[:, 1].min() - pad, 0, h - 1))
    x1, y1 = int(np.clip(v[:, 0].max() + pad + 1, x0 + 1, w)), int(np.clip(v[:, 1].max() + pad + 1, y0 + 1, h))
    m = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(m, [(v - [x0, y0]).astype(np.int32).reshape(-1, 1, 2)], 1)
    return m.astype(bool), x0, y0


def shrunk_pixels(shape: tuple[int, int], vertices: np.ndarray, erode_px: int) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (xs, ys) inside the polygon of ``vertices`` at least ``erode_px`` px from its edges
    (the image border is no edge)."""
    import cv2

    mask, x0, y0 = polygon_mask(shape, vertices, pad=erode_px + 1)
    if erode_px:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((2 * erode_px + 1,) * 2, np.uint8)).astype(bool)
    ys, xs = np.nonzero(mask)
    return xs + x0, ys + y0


def check_points(frame: Frame, points: object, least: int, what: str) -> np.ndarray:
    """``points`` as an n x 2 float array of clicks inside the image, n >= ``least``; MeasureError otherwise."""
    try:
        seq = list(points)  # type: ignore[call-overload]
    except TypeError as exc:
        raise MeasureError(f"{what} needs a list of (x, y) clicks, got {points!r}") from exc
    if len(seq) < least:
        raise MeasureError(f"{what} needs at least {least} clicks, got {len(seq)}; add points")
    return np.array([check_point(frame, p, f"point {i + 1}") for i, p in enumerate(seq)], dtype=float)


def check_options(options: MeasureOptions | None) -> MeasureOptions:
    """``options`` or the defaults; MeasureError for anything that is not MeasureOptions."""
    if options is None:
        return MeasureOptions()
    if not isinstance(options, MeasureOptions):
        raise MeasureError(f"options must be a measure.MeasureOptions, got {type(options).__name__}")
    return options


def verdict(value: float, sigma: float, reasons: list[str], unreliable: bool) -> tuple[str, tuple[str, ...], tuple[float, float]]:
    """Quality, reasons and the 95 % interval of a shape value (``measure.verdict.judge`` on it)."""
    half = INTERVAL_Z * sigma
    quality, out = judge(reasons, None, abs(value), half)
    if unreliable:
        quality = "unreliable"
    return quality, out, (value - half, value + half)
