"""Length, width and height of a box standing on a plane, from one click on its top face (m).

Steps (docs/method.md Eq. 9-15):

1. The top face: the robust plane grown from the click over its connected surface
   (``measure.planes.grow_plane``); its outline is where the disparity leaves that plane (a depth
   step to the floor, or the crease to a side face), not a bounding box of noisy points.
2. The supporting plane: the densest level parallel to the top and below it in a ring around the
   face, or the level seen at the box's foot where the densest is not (``measure.support.parallel_levels``).
   None found: the click is not on a box top (MeasureError).
3. The rectangle: the outline's pixels are put on the top plane (Eq. 2, 9); a minimum-area rectangle
   gives the orientation, refined from the sides' own directions; each side first lies at the median
   offset of its outline pixels plus half a pixel's footprint outward (Eq. 15), from the middle
   ``SIDE_SPAN`` of its length. Then each side goes where the colour image steps within the depth's
   window (``measure.box_edges``), and the rectangle turns by those sides' mean tilt.
4. The face's own plane: refit on the pixels inside the found rectangle, clear of its sides
   (``_face_plane``); the rectangle's corners, lines in the image, are put on it, and the lengths
   are the means of opposite sides. The height: the rectangle's centre on that plane above the
   supporting plane (``measure.height.height_above``, Eq. 12).
5. One-sigma per length: both sides' (the image edge's, or the depth's with the fattening reach) and
   the face plane's covariance through its sigma points and a disparity offset common to the frame
   (``measure.planes.CALIBRATION_PX``), in quadrature; times ``BOX_SIGMA_SCALE``
   (docs/decisions/box-edges.md). The verdict says "check" for a box cut by the image border, a side
   that shows no step in the colour image, a face partly hidden by something in front, a top that is
   not rectangular or not parallel to its floor, or a grown top whose plane is not the click window's
   own (``measure.planes.joined_another``: a neighbouring box's top joined it).
"""

from __future__ import annotations

import math
import time

import numpy as np

from measure.box_edges import AXES, CORRELATED_PX, FATTEN_REACH_PX, MIN_SIDE_POINTS, SIDE_SPAN, RectFrame, find_side
from measure.height import height_above, window_plane
from measure.planes import INLIER_SIGMAS, GrownPlane, Plane, fit_plane, grow_plane, joined_another, offset_plane, sigma_of
from measure.sampling import check_point
from measure.shape_types import BoxMeasurement
from measure.support import angle_deg, check_options, cross2, parallel_levels, shrunk_pixels, verdict
from measure.types import Frame, MeasureError, MeasureOptions

BOX_SIGMA_SCALE = 1.0
MIN_TOP_PX = 60
FACE_SHARE = 0.25
EDGE_MARGIN_PX = 2.0
FEW_TOP_PX = 300
MIN_HEIGHT_M = 0.02
FILL_MIN = 0.88
HIDDEN_SHARE = 0.25
OUTSIDE_PX = 6.0
TILT_DEG = 5.0


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
        along, across, sign = AXES[k]
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
    rf = RectFrame(pc, u, v, np.array([ra, rb]), e)
    # The face's pixels against the outline's own rectangle: a top that is no rectangle fills it poorly.
    cpx = rf.to_px(top, _corners(pos))
    area_px = 0.5 * abs(float(cross2(cpx[1] - cpx[0], cpx[2] - cpx[0]) + cross2(cpx[2] - cpx[0], cpx[3] - cpx[0])))
    sides = [find_side(frame, top, rf, pos, k, float(sig[k])) if seen[k] else None for k in range(4)]
    rf, pos, sig = _placed(rf, pos, sig, sides)
    return {"rf": rf, "pos": pos, "sig": sig, "seen": seen, "outward": outward, "sides": sides,
            "fill": float(grown.mask.sum()) / area_px if area_px > 0 else 0.0,
            "line": line, "side": side, "inner": inner, "centre_px": centre_px}


def _corners(pos: np.ndarray) -> np.ndarray:
    """Rectangle coordinates (4 x 2, m) of the corners of the rectangle whose sides lie at ``pos``, in order around it."""
    return np.array([[-pos[1], -pos[3]], [pos[0], -pos[3]], [pos[0], pos[2]], [-pos[1], pos[2]]])


def _placed(rf: RectFrame, pos: np.ndarray, sig: np.ndarray, sides: list) -> tuple[RectFrame, np.ndarray, np.ndarray]:
    """The rectangle turned by the image-found sides' weighted mean tilt, and every side's position
    (m) measured again across the turned axes from its own middle."""
    tilts = [(-sd.tilt if k < 2 else sd.tilt, sd.tilt_weight) for k, sd in enumerate(sides) if sd is not None and sd.tilt_weight > 0]
    turn = float(np.average([t for t, _ in tilts], weights=[wt for _, wt in tilts])) if tilts else 0.0
    c, sn = math.cos(turn), math.sin(turn)
    e2 = np.array([[c, sn], [-sn, c]]) @ rf.e
    new_pos, new_sig = pos.copy(), sig.copy()
    for k in range(4):
        along, across, sign = AXES[k]
        p = sides[k].pos if sides[k] is not None else pos[k]
        lo, hi = (-pos[3], pos[2]) if along == 1 else (-pos[1], pos[0])
        mid = np.zeros(2)
        mid[along], mid[across] = (lo + hi) / 2.0, sign * p
        new_pos[k] = sign * float((mid @ rf.e) @ e2[across])
        if sides[k] is not None:
            new_sig[k] = sides[k].sigma
    return RectFrame(rf.pc, rf.u, rf.v, rf.centre, e2), new_pos, new_sig


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


def _lengths(c: np.ndarray) -> np.ndarray:
    """The two side lengths (m) of a quadrilateral of corners ``c`` (4 x 3, in order): each the mean of its pair."""
    side = np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)
    return np.array([(side[0] + side[2]) / 2.0, (side[1] + side[3]) / 2.0])


def _face_plane(frame: Frame, grown: GrownPlane, rect: dict) -> Plane:
    """The top's plane refit on the pixels of its found rectangle clear of its sides: ``FATTEN_REACH_PX``
    inside a crease, ``EDGE_MARGIN_PX`` inside a depth step, and at most ``FACE_SHARE`` of the
    rectangle's width from each side. The grown face also holds side-face pixels beyond its creases
    (within its tolerance for a few to tens of pixels), and the face's own pixels next to a crease
    take the ridge's disparity where the matcher flattens it: both tilt its plane, which shortens the
    foreshortened side and lowers the height at the centre (docs/decisions/box-edges.md). With fewer
    than ``MIN_TOP_PX`` such pixels the grown plane stays."""
    pos, sides = rect["pos"].copy(), rect["sides"]
    for k, sd in enumerate(sides):
        if sd is not None:
            margin = (FATTEN_REACH_PX if sd.crease else EDGE_MARGIN_PX) * sd.foot
            pos[k] -= min(margin, FACE_SHARE * (pos[k] + pos[k ^ 1]))
    xs, ys = shrunk_pixels(frame.shape, rect["rf"].to_px(grown.plane, _corners(pos)), 0)
    if len(xs) < MIN_TOP_PX:
        return grown.plane
    try:
        return fit_plane(frame, xs, ys, seed=0, start=grown.plane)
    except MeasureError:
        return grown.plane


def _on_face(face: Plane, floor: Plane, cpx: np.ndarray, sig: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[float], tuple[float, float]]:
    """Step 4-5: the corners (4 x 3, m) where the found rectangle's corner pixels ``cpx`` meet the face
    plane, the two lengths (m) and their one-sigmas from the sides' ``sig`` (m) and the plane's sigma
    points, and the height (m) of the rectangle's centre above ``floor`` with its one-sigma."""
    corners = face.points_at(cpx[:, 0], cpx[:, 1])
    dims = _lengths(corners)
    # The plane's uncertainty moves the corners along their rays: its sigma points give the lengths' spread.
    spread = sigma_of(np.array([_lengths(face.points_at(cpx[:, 0], cpx[:, 1], c)) for c in face.coefficient_samples()]))
    offset = np.abs(_lengths(offset_plane(face).points_at(cpx[:, 0], cpx[:, 1])) - dims)
    sig_dims = [math.sqrt(sig[0] ** 2 + sig[1] ** 2 + spread[0] ** 2 + offset[0] ** 2),
                math.sqrt(sig[2] ** 2 + sig[3] ** 2 + spread[1] ** 2 + offset[1] ** 2)]
    cx, cy = (float(v) for v in cpx.mean(axis=0))
    height, s_h, _, _ = height_above(face, floor, cx, cy, 0.0)
    return corners, dims, sig_dims, (height, s_h)


def _reasons(frame: Frame, grown: GrownPlane, rect: dict, between: bool, merged: bool) -> list[str]:
    """Why the answer is one to check, from what the face, its sides and its surroundings showed."""
    reasons: list[str] = []
    if grown.touches_border or not rect["seen"].all():
        reasons.append("box cut by the image border" if grown.touches_border else "an edge of the top face is not seen")
    if any(sd is not None and sd.source != "image" for sd in rect["sides"]):
        reasons.append("an edge of the top face shows no step in the colour image (placed from the depth alone)")
    if between:
        reasons.append("another level lies between the top and the plane it is measured from (a table or a neighbouring box)")
    if merged:
        reasons.append("the grown top is not the clicked face's plane (another surface joined it)")
    if _hidden_sides(frame, grown.plane, rect):
        reasons.append("top face partly hidden by something in front")
    if rect["fill"] < FILL_MIN:
        reasons.append(f"top face not rectangular ({100 * rect['fill']:.0f} % of its rectangle)")
    return reasons


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
    window = window_plane(frame, x, y, opts.seed)
    grown = grow_plane(frame, (x, y), opts.seed, window=window)
    n_top = int(grown.mask.sum())
    if n_top < MIN_TOP_PX:
        raise MeasureError(f"the clicked face has only {n_top} pixels with depth; click the top face of a box nearer the camera")
    top, mask = grown.plane, grown.mask
    floor, between = parallel_levels(frame, mask, top, seed=opts.seed, min_drop_m=MIN_HEIGHT_M)
    if floor is None:
        raise MeasureError("no plane parallel to the clicked surface lies below it: this is not the top face of a box "
                           "standing on a floor or table (a click on the floor itself, a wall or a side face); "
                           "click the box's top face")
    rect = _rectangle(top, grown, frame)
    cpx = rect["rf"].to_px(top, _corners(rect["pos"]))
    face = _face_plane(frame, grown, rect)
    corners, dims, sig_dims, (height, s_h) = _on_face(face, floor, cpx, rect["sig"])
    reasons = _reasons(frame, grown, rect, between, joined_another(window, top, x, y))
    fn, fo = floor.metric()
    base = corners - (corners @ fn + fo)[:, None] * fn

    def to_px(p: np.ndarray) -> np.ndarray:
        return np.stack([top.fx * p[:, 0] / p[:, 2] + top.cx, top.fy * p[:, 1] / p[:, 2] + top.cy], 1)

    tilt = angle_deg(face, floor)
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
