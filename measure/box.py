"""Length, width and height of a box standing on a plane, from one click on its top face (m).

Steps (docs/method.md Eq. 9-15):

1. The top face: the robust plane grown from the click over its connected surface
   (``measure.planes.grow_plane``); its outline is where the disparity leaves that plane (a depth
   step to the floor, or the crease to a side face), not a bounding box of noisy points.
2. The supporting plane: the robust plane around the top face, parallel to it and below it
   (``measure.support.support_plane``). None found: the click is not on a box top (MeasureError).
3. The rectangle: the outline's pixels are put on the top plane (Eq. 2, 9); a minimum-area rectangle
   gives the orientation, refined from the sides' own directions; each side lies at the median
   offset of its outline pixels plus half a pixel's footprint outward (Eq. 15), from the middle
   ``SIDE_SPAN`` of its length (corners are where outliers gather). Image-border pixels are no edge.
4. The height: the top's centre above the supporting plane (``measure.height.height_above``, Eq. 12),
   the top's plane refit on its interior, ``CREASE_BAND_PX`` inside the outline (side-face pixels near
   a crease lie within the grown plane's tolerance and pull it down).
5. One-sigma per dimension: both sides' median errors (MAD / sqrt(n / ``CORRELATED_PX``)), a
   pixel's footprint over sqrt(3) each, ``BLEED_PX`` footprints for a side against the background
   (edge fattening of unknown width), the plane's depth scale, and half the difference between the
   outline's and the creases' sides (two models of one edge); times ``BOX_SIGMA_SCALE``
   (docs/decisions/box-edges.md). The verdict says "check" for a box cut by the image border, a face
   partly hidden by something in front, a top that is not rectangular or not parallel to its floor,
   edge models that differ by more than ``EDGE_DISAGREE`` of a side, or a grown top whose plane is not
   the click window's own (``MERGED_SIGMAS``: a neighbouring box's top joined it).
"""

from __future__ import annotations

import math
import time

import numpy as np

from measure.height import height_above, window_plane
from measure.planes import INLIER_SIGMAS, GrownPlane, Plane, fit_plane, grow_plane, sigma_of
from measure.sampling import check_point
from measure.shape_types import BoxMeasurement
from measure.support import angle_deg, check_options, cross2, parallel_levels, verdict
from measure.types import Frame, MeasureError, MeasureOptions

BOX_SIGMA_SCALE = 1.0
MIN_TOP_PX = 60
FEW_TOP_PX = 300
MIN_HEIGHT_M = 0.02
SIDE_SPAN = 0.8
CORRELATED_PX = 4.0
BLEED_PX = 1.0
FILL_MIN = 0.88
HIDDEN_SHARE = 0.25
OUTSIDE_PX = 6.0
TILT_DEG = 5.0
MIN_SIDE_POINTS = 8
CREASE_BAND_PX = 14
CREASE_RESIDUAL = 4.0
CREASE_GAIN = 25.0
CREASE_BINS = 5
EDGE_DISAGREE = 0.05
MERGED_SIGMAS = 4.0


def _outline(mask: np.ndarray) -> np.ndarray:
    """The outer outline of the largest region of ``mask``: n x 2 int (x, y) px."""
    import cv2

    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2), np.int64)
    return max(contours, key=len).reshape(-1, 2).astype(np.int64)


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u = np.array([1.0, 0.0, 0.0]) - n[0] * n
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _sides(q: np.ndarray, theta: float, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates of 2D points ``q`` along the rectangle's axes and the side (0..3: +e1, -e1, +e2, -e2) each is nearest."""
    e = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])
    s = q @ e.T
    dist = np.stack([np.abs(s[:, 0] - half[0]), np.abs(s[:, 0] + half[0]), np.abs(s[:, 1] - half[1]), np.abs(s[:, 1] + half[1])], 1)
    return s, np.argmin(dist, axis=1)


def _refine_angle(s: np.ndarray, side: np.ndarray, half: np.ndarray) -> float:
    """Weighted mean tilt (rad) of the sides' own least-squares directions against the rectangle's axes."""
    tilts, weights = [], []
    for k in range(4):
        along, across = (1, 0) if k < 2 else (0, 1)
        pts = s[side == k]
        lim = SIDE_SPAN * half[along]
        pts = pts[np.abs(pts[:, along]) <= lim]
        if len(pts) < MIN_SIDE_POINTS:
            continue
        t, c = pts[:, along] - pts[:, along].mean(), pts[:, across] - pts[:, across].mean()
        slope = float(t @ c / (t @ t)) if t @ t > 0 else 0.0
        # +e1 sides run along e2: a slope dc/dt rotates them by -atan(slope); e2 sides by +atan.
        tilts.append(-math.atan(slope) if k < 2 else math.atan(slope))
        weights.append(len(pts))
    return float(np.average(tilts, weights=weights)) if tilts else 0.0


def _rectangle(top: Plane, grown: GrownPlane, frame: Frame) -> dict:
    """Step 3: the top face's rectangle in the plane and what each side saw."""
    import cv2

    h, w = frame.shape
    line = _outline(grown.mask)
    inner = (line[:, 0] > 0) & (line[:, 0] < w - 1) & (line[:, 1] > 0) & (line[:, 1] < h - 1)
    n = top.metric()[0]
    ys, xs = np.nonzero(grown.mask)
    centre_px = (float(xs.mean()), float(ys.mean()))
    pc = top.points_at(*centre_px)
    u, v = _basis(n)
    pts = top.points_at(line[:, 0], line[:, 1])
    q = np.stack([(pts - pc) @ u, (pts - pc) @ v], axis=1)
    (ra, rb), (rw, rh), ang = cv2.minAreaRect(q[inner if inner.sum() >= 4 else slice(None)].astype(np.float32))
    theta, half = math.radians(ang), np.array([rw, rh]) / 2
    q = q - np.array([ra, rb])
    s, side = _sides(q, theta, half)
    theta += _refine_angle(s[inner], side[inner], half)
    s, side = _sides(q, theta, half)
    # Half a pixel's footprint outward: the edge lies between the last pixel on the face and the next.
    jx = top.points_at(line[:, 0] + 0.5, line[:, 1]) - top.points_at(line[:, 0] - 0.5, line[:, 1])
    jy = top.points_at(line[:, 0], line[:, 1] + 0.5) - top.points_at(line[:, 0], line[:, 1] - 0.5)
    e = np.array([[math.cos(theta), math.sin(theta)], [-math.sin(theta), math.cos(theta)]])
    pos, sig, seen, outward = np.zeros(4), np.zeros(4), np.zeros(4, bool), []
    for k in range(4):
        along, across, sign = (1, 0, 1.0) if k == 0 else (1, 0, -1.0) if k == 1 else (0, 1, 1.0) if k == 2 else (0, 1, -1.0)
        m3 = sign * (e[across, 0] * u + e[across, 1] * v)
        outward.append(m3)
        sel = inner & (side == k) & (np.abs(s[:, along]) <= SIDE_SPAN * half[along])
        foot = 0.5 * (np.abs(jx @ m3) + np.abs(jy @ m3))
        if sel.sum() >= MIN_SIDE_POINTS:
            o = s[sel, across] * sign
            med = float(np.median(o))
            mad = 1.4826 * float(np.median(np.abs(o - med)))
            f = float(np.median(foot[sel]))
            pos[k] = med + f
            sig[k] = math.hypot(1.2533 * mad / math.sqrt(sel.sum() / CORRELATED_PX), f / math.sqrt(3.0))
            seen[k] = True
        else:  # the side is off the image or hidden: the rectangle's own side stands in
            pos[k] = half[across]
            f = float(np.median(foot)) if len(foot) else 0.0
            sig[k] = max(float(half[across]) * 0.1, f)
        sig[k] = math.hypot(sig[k], BLEED_PX * float(np.median(foot[side == k])) if (side == k).any() else 0.0)
    creases = _creases(frame, top, grown.mask, pc, u, v, np.array([ra, rb]), e, pos, half, seen)
    outline_pos = pos.copy()
    pos = np.where(np.isfinite(creases), creases, pos)
    return {"pc": pc, "u": u, "v": v, "e": e, "pos": pos, "outline_pos": outline_pos, "sig": sig, "seen": seen, "outward": outward,
            "line": line, "side": side, "inner": inner, "centre_px": centre_px, "ra_rb": np.array([ra, rb])}


def _creases(frame: Frame, top: Plane, mask: np.ndarray, pc: np.ndarray, u: np.ndarray, v: np.ndarray,
             centre: np.ndarray, e: np.ndarray, pos: np.ndarray, half: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Eq. 16: each side's crease with the face beyond it, where the disparity residual to the top plane
    starts a linear trend: a hinge fit to the residual's medians in one-pixel bins across the band of
    ``CREASE_BAND_PX`` either side of the side. The trend must be significant, reach the inlier
    tolerance within the band and be seen in ``CREASE_BINS`` bins beyond the hinge (a face, not the
    thin fattened halo beyond a depth step). NaN for a side without: its outline stands."""
    import cv2

    ys, xs = np.nonzero(cv2.dilate(mask.astype(np.uint8), np.ones((2 * CREASE_BAND_PX + 1,) * 2, np.uint8)))
    r = frame.disparity[ys, xs] - top.disparity_at(xs, ys)
    tol = INLIER_SIGMAS * max(top.sigma_px, top.quantum * 0.75)
    keep = np.abs(r) <= CREASE_RESIDUAL * tol  # outliers and the background beyond a depth step drop out
    xs, ys, r = xs[keep], ys[keep], r[keep]
    p3 = top.points_at(xs, ys)
    s = (np.stack([(p3 - pc) @ u, (p3 - pc) @ v], axis=1) - centre) @ e.T
    foot = float(np.median(np.linalg.norm(top.points_at(xs + 1.0, ys) - p3, axis=1))) if len(xs) else 0.0
    out = np.full(4, np.nan)
    noise2 = (1.2533 * max(top.sigma_px, top.quantum / math.sqrt(12.0))) ** 2 * CORRELATED_PX
    nb = 2 * CREASE_BAND_PX
    centres = (np.arange(nb) - CREASE_BAND_PX + 0.5) * foot
    for k in range(4):
        if not seen[k] or foot <= 0:
            continue
        along, across, sign = (1, 0, 1.0) if k == 0 else (1, 0, -1.0) if k == 1 else (0, 1, 1.0) if k == 2 else (0, 1, -1.0)
        t = sign * s[:, across] - pos[k]
        sel = (np.abs(s[:, along]) <= SIDE_SPAN * half[along]) & (np.abs(t) < CREASE_BAND_PX * foot)
        b = np.floor(t[sel] / foot).astype(int) + CREASE_BAND_PX
        rk = r[sel]
        counts = np.bincount(b, minlength=nb)[:nb]
        order = np.argsort(b, kind="stable")
        groups = np.split(rk[order], np.cumsum(counts)[:-1])
        med = np.array([float(np.median(g)) if len(g) else 0.0 for g in groups])
        w = counts.astype(float)
        grid = np.arange(-CREASE_BAND_PX, 0.25, 0.25) * foot
        hinge = np.maximum(centres[None, :] - grid[:, None], 0.0)
        su, sru = (w * hinge**2).sum(axis=1), (w * hinge * med).sum(axis=1)
        gain = np.where(su > 0, sru**2 / np.maximum(su, 1e-30), 0.0)
        best = int(np.argmax(gain))
        slope = sru[best] / su[best] if su[best] > 0 else 0.0
        reach = abs(slope) * (CREASE_BAND_PX * foot - grid[best])
        beyond = int(((centres > grid[best]) & (counts >= MIN_SIDE_POINTS)).sum())
        if gain[best] > CREASE_GAIN * noise2 and reach >= tol and beyond >= CREASE_BINS:
            out[k] = pos[k] + grid[best]
    return out


def _hidden_sides(frame: Frame, top: Plane, rect: dict) -> list[int]:
    """Sides whose pixels just outside are nearer than the top plane: something in front hides them."""
    h, w = frame.shape
    out = []
    line, side = rect["line"], rect["side"]
    for k in range(4):
        sel = rect["inner"] & (side == k)
        if sel.sum() < MIN_SIDE_POINTS:
            continue
        px = line[sel].astype(float)
        d0 = top.disparity_at(px[:, 0], px[:, 1])
        # Step OUTSIDE_PX px outward in the image along the side's outward direction.
        p3 = top.points_at(px[:, 0], px[:, 1])
        ahead = p3 + 0.01 * rect["outward"][k]
        img = np.stack([top.fx * ahead[:, 0] / ahead[:, 2] + top.cx, top.fy * ahead[:, 1] / ahead[:, 2] + top.cy], 1)
        step = img - px
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        look = np.rint(px + OUTSIDE_PX * step / np.maximum(norm, 1e-9)).astype(int)
        ok = (look[:, 0] >= 0) & (look[:, 0] < w) & (look[:, 1] >= 0) & (look[:, 1] < h)
        if ok.sum() < MIN_SIDE_POINTS:
            continue
        d = frame.disparity[look[ok, 1], look[ok, 0]]
        tol = INLIER_SIGMAS * max(top.sigma_px, top.quantum) + 0.5
        with np.errstate(invalid="ignore"):
            nearer = d > d0[ok] + tol
        if float(nearer.mean()) > HIDDEN_SHARE:
            out.append(k)
    return out


def _interior_plane(frame: Frame, grown: GrownPlane, seed: int) -> Plane:
    """The grown top's plane refit on the pixels at least ``CREASE_BAND_PX`` inside its outline, for the
    height at the top's centre.

    Near a crease the side face stays within the top's inlier tolerance for a few pixels (the more
    noise, the wider the tolerance): grown over, they pull the plane down towards the sides and the
    height at the centre with it. The crease band is where a side face can hide in the top's tolerance,
    so the height's plane comes from inside it. The rectangle keeps the grown plane: at range the
    interior is few pixels, and the outline's pixels are projected best by the plane fit over them
    all (measured: docs/decisions/shape-uncertainty.md). With fewer than ``MIN_TOP_PX`` interior
    pixels (a small or far top) the grown plane stays.
    """
    import cv2

    k = 2 * CREASE_BAND_PX + 1
    inner = cv2.erode(grown.mask.astype(np.uint8), np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE).astype(bool)
    if int(inner.sum()) < MIN_TOP_PX:
        return grown.plane
    ys, xs = np.nonzero(inner)
    try:
        return fit_plane(frame, xs, ys, seed, start=grown.plane)
    except MeasureError:
        return grown.plane


def _not_the_clicked_plane(frame: Frame, top: Plane, x: float, y: float, seed: int) -> bool:
    """Whether the plane of the click's own window differs from the grown top's at the click by more
    than ``MERGED_SIGMAS`` of their combined disparity one-sigma (Eq. 11 covariances): a neighbour's top
    a few centimetres higher or lower joined the grown face and tilted or shifted its plane."""
    try:
        own = window_plane(frame, x, y, seed)
    except MeasureError:
        return False
    g = np.array([x, y, 1.0])
    diff = float(own.disparity_at(x, y) - top.disparity_at(x, y))
    return abs(diff) > MERGED_SIGMAS * math.sqrt(float(g @ own.cov @ g + g @ top.cov @ g))


def measure_box(frame: Frame, click_px: tuple[float, float], options: MeasureOptions | None = None) -> BoxMeasurement:
    """Dimensions (m) of the box whose top face is clicked at ``click_px`` (x, y px); steps in the module docstring.

    Returns:
        A :class:`BoxMeasurement` with ``length_m >= width_m``, ``height_m``, their one-sigmas, the verdict
        and the top face's corners (3D and px) with their feet on the supporting plane.

    Raises:
        MeasureError: the click is outside the image, on no surface with depth, or not on the top of
            something standing on a plane (the floor itself, a wall, a side face).
    """
    t0 = time.perf_counter()
    opts = check_options(options)
    x, y = check_point(frame, click_px, "click_px")
    grown = grow_plane(frame, (x, y), opts.seed)
    n_top = int(grown.mask.sum())
    if n_top < MIN_TOP_PX:
        raise MeasureError(f"the clicked face has only {n_top} pixels with depth; click the top face of a box nearer the camera")
    top, mask = grown.plane, grown.mask
    ys, xs = np.nonzero(mask)
    cx, cy = float(xs.mean()), float(ys.mean())
    merged = _not_the_clicked_plane(frame, top, x, y, opts.seed)
    floor, between = parallel_levels(frame, mask, top, seed=opts.seed, min_drop_m=MIN_HEIGHT_M)
    if floor is None:
        raise MeasureError("no plane parallel to the clicked surface lies below it: this is not the top face of a box "
                           "standing on a floor or table (a click on the floor itself, a wall or a side face); "
                           "click the box's top face")
    rect = _rectangle(top, grown, frame)
    pos, sig = rect["pos"], rect["sig"]
    # Depth scale: every in-plane length scales with the plane's distance from the camera.
    n, o = top.metric()
    offs = np.array([top.metric(c)[1] for c in top.coefficient_samples()])
    rel_scale = float(sigma_of(offs)) / o
    dims = [pos[0] + pos[1], pos[2] + pos[3]]
    sig_dims = [math.sqrt(sig[0] ** 2 + sig[1] ** 2 + (dims[0] * rel_scale) ** 2),
                math.sqrt(sig[2] ** 2 + sig[3] ** 2 + (dims[1] * rel_scale) ** 2)]
    # The two edge models, the outline's depth step and the crease's hinge, bracket each side: their
    # difference is an uncertainty of the model, and a large one a reason to check the answer.
    outline = rect["outline_pos"]
    spread = [abs(dims[0] - outline[0] - outline[1]), abs(dims[1] - outline[2] - outline[3])]
    sig_dims = [math.hypot(s, d / 2.0) for s, d in zip(sig_dims, spread)]
    height, s_h, _, _ = height_above(_interior_plane(frame, grown, opts.seed), floor, cx, cy, 0.0)
    reasons: list[str] = []
    worst = max(d / v for d, v in zip(spread, dims)) if min(dims) > 0 else math.inf
    if worst > EDGE_DISAGREE:
        reasons.append(f"top face's edges uncertain (outline and creases differ by {100 * worst:.0f} %)")
    if grown.touches_border or not rect["seen"].all():
        reasons.append("box cut by the image border" if grown.touches_border else "an edge of the top face is not seen")
    if between:
        reasons.append("another level lies between the top and the plane it is measured from (a table or a neighbouring box)")
    if merged:
        reasons.append("the grown top is not the clicked face's plane (another surface joined it)")
    hidden = _hidden_sides(frame, top, rect)
    if hidden:
        reasons.append("top face partly hidden by something in front")
    e, pc, u, v = rect["e"], rect["pc"], rect["u"], rect["v"]
    centre2 = rect["ra_rb"] + e[0] * (pos[0] - pos[1]) / 2 + e[1] * (pos[2] - pos[3]) / 2
    corners2 = [centre2 + a * e[0] * dims[0] / 2 + b * e[1] * dims[1] / 2 for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    corners = np.array([pc + c[0] * u + c[1] * v for c in corners2])
    fn, fo = floor.metric()
    base = corners - (corners @ fn + fo)[:, None] * fn

    def to_px(p: np.ndarray) -> np.ndarray:
        return np.stack([top.fx * p[:, 0] / p[:, 2] + top.cx, top.fy * p[:, 1] / p[:, 2] + top.cy], 1)

    cpx = to_px(corners)
    rect_px_area = 0.5 * abs(float(cross2(cpx[1] - cpx[0], cpx[2] - cpx[0]) + cross2(cpx[2] - cpx[0], cpx[3] - cpx[0])))
    fill = n_top / rect_px_area if rect_px_area > 0 else 0.0
    if fill < FILL_MIN:
        reasons.append(f"top face not rectangular ({100 * fill:.0f} % of its rectangle)")
    tilt = angle_deg(top, floor)
    if tilt > TILT_DEG:
        reasons.append(f"top face not parallel to the floor ({tilt:.0f} degrees)")
    few = n_top < FEW_TOP_PX
    if few:
        reasons.append("few pixels on the top face")
    values = [dims[0], dims[1], height]
    sigmas = [s * BOX_SIGMA_SCALE for s in (*sig_dims, s_h)]
    verdicts = [verdict(val, s, reasons, unreliable=few) for val, s in zip(values, sigmas)]
    order = ("good", "check", "unreliable")
    quality = max((q for q, _, _ in verdicts), key=order.index)
    why = tuple(dict.fromkeys(r for _, rs, _ in verdicts for r in rs))
    intervals = [iv for _, _, iv in verdicts]
    if dims[1] > dims[0]:  # length is the longer side
        values[0], values[1] = values[1], values[0]
        sigmas[0], sigmas[1] = sigmas[1], sigmas[0]
        intervals[0], intervals[1] = intervals[1], intervals[0]
    return BoxMeasurement(
        length_m=float(values[0]), width_m=float(values[1]), height_m=float(values[2]),
        uncertainty_m=tuple(float(s) for s in sigmas), intervals_m=tuple(tuple(map(float, iv)) for iv in intervals),
        quality=quality, reasons=why,
        corners_m=tuple(tuple(map(float, c)) for c in corners), base_corners_m=tuple(tuple(map(float, c)) for c in base),
        corners_px=tuple(tuple(map(float, c)) for c in cpx), base_corners_px=tuple(tuple(map(float, c)) for c in to_px(base)),
        support_plane=(*map(float, fn), float(fo)), click_px=(x, y), n_top_px=n_top,
        elapsed_ms=(time.perf_counter() - t0) * 1000.0,
    )
