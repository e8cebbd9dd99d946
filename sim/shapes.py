"""Simulated scenes with ground truth for the shape measurements: boxes on a floor or a table, and panels.

World frame as in ``sim.scenes`` (floor at Y = 0, Y down, metres). A box case draws from its seed a box
of 10-80 cm per side at a yaw, standing on the floor or on a table, seen from ``range_m`` (0.6-3 m, to
the top face's centre) looking down at 30-65 degrees; variants put it partly outside the image
("cut") or beside a second box ("beside"); the click is on the top's centre, or its shown pixel nearest
the centre where the box beside it hides that. Its truth: length >= width of the top face, height above
what it stands on, the top's corners in the image, and how much of the top face is visible. A panel
case is a framed board 2 cm proud of a wall, its four corners clicked. Frames go through the rig's
sensor model (``sim.sensor``) with a profile ("stress" or "paper").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from measure import Frame

from sim.raycast import Box, Pose, Rect
from sim.scenario import frame_from_view, make_model
from sim.scenes import SceneParams, SceneSpec, make_view, reference_camera

BOX_VARIANTS: tuple[str, ...] = ("plain", "cut", "beside")
TABLE_HEIGHT_M = 0.75
CLICK_SIGMA_PX = 1.5


@dataclass(frozen=True)
class BoxCase:
    """A simulated box: the frame, the click on its top, the truth (m, px) and how it was drawn."""

    frame: Frame
    click_px: tuple[float, float]
    length_m: float
    width_m: float
    height_m: float
    corners_px: tuple[tuple[float, float], ...]  # the top face's true corners, in order around it
    visible: float  # share of the top face's pixels in the image and not hidden
    variant: str
    support: str  # "floor" | "table"
    range_m: float
    base_px: tuple[tuple[float, float], ...]  # a region of the supporting surface in front of the box
    support_plane: tuple[float, float, float, float]  # the surface it stands on, camera frame: n . P + o = 0, n to the camera


@dataclass(frozen=True)
class PanelCase:
    """A simulated framed panel on a wall: frame, clicked corners (px), true area (m²), range (m)."""

    frame: Frame
    clicks_px: tuple[tuple[float, float], ...]
    area_m2: float
    range_m: float


def _look(target: np.ndarray, range_m: float, down_deg: float, heading_deg: float = 0.0) -> Pose:
    """A camera ``range_m`` from ``target`` (world), looking straight at it ``down_deg`` below the horizon."""
    phi = math.radians(down_deg)
    centre = target + np.array([0.0, -range_m * math.sin(phi), -range_m * math.cos(phi)])
    return Pose.looking(tuple(float(v) for v in centre), phi)


def _project(pose: Pose, frame: Frame, pts: np.ndarray) -> np.ndarray:
    return pose.project(frame.camera, pts)


def _sensed(params: SceneParams, spec: SceneSpec, pose: Pose, profile: str, lighting: str, rng: np.random.Generator):
    view = make_view(params, spec, reference_camera(params.width, params.height), pose)
    return view, frame_from_view(view, make_model(lighting, profile), rng, timestamp=0.0, meta={"source": "sim"})


def box_case(seed: int, profile: str = "stress", lighting: str = "indoor", range_m: float | None = None,
             variant: str | None = None, width: int = 1280, height: int = 720) -> BoxCase:
    """The box case of ``seed`` (see the module docstring); ``range_m`` and ``variant`` fix those draws."""
    rng = np.random.default_rng([seed, 0xB0C5])
    r = float(rng.uniform(0.6, 3.0)) if range_m is None else float(range_m)
    var = variant or str(rng.choice(BOX_VARIANTS, p=[0.7, 0.15, 0.15]))
    support = "table" if rng.random() < 0.25 else "floor"
    base_y = -TABLE_HEIGHT_M if support == "table" else 0.0
    down = float(rng.uniform(30.0, 65.0))
    yaw = float(rng.uniform(0.0, math.pi / 2))
    cam = reference_camera(width, height)
    # The largest side that fits: the top's diagonal within 70 % of the image height at this range.
    fit = 0.7 * height / cam.fy * r / math.sqrt(2)
    top_hi = max(0.1, min(0.8, fit))
    lx, lz = (float(rng.uniform(0.1, top_hi)) for _ in range(2))
    h = float(rng.uniform(0.1, min(0.8, max(0.12, 0.9 * r * math.sin(math.radians(down))))))
    top_centre = np.array([0.0, base_y - h, 0.0])
    prims = [Rect((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (40.0, 40.0), "wood", "floor")]
    if support == "table":
        half = (max(lx, lz) + 0.3, max(lx, lz) + 0.3)
        prims.append(Box((0.0, base_y + 0.02, 0.0), (half[0], 0.02, half[1]), "wood", "table"))
        for sx in (-1, 1):
            for sz in (-1, 1):
                prims.append(Box((sx * (half[0] - 0.05), base_y / 2 + 0.02, sz * (half[1] - 0.05)),
                                 (0.025, -base_y / 2 - 0.02, 0.025), "wood", "table"))
    box = Box((0.0, base_y - h / 2, 0.0), (lx / 2, h / 2, lz / 2), "cardboard", "box", yaw_rad=yaw)
    prims.append(box)
    if var == "beside":
        h2 = float(np.clip(h * rng.uniform(0.6, 1.6), 0.1, 0.9))
        s2 = float(rng.uniform(0.15, 0.5))
        gap = float(rng.uniform(0.02, 0.2))
        side = float(rng.choice([-1.0, 1.0]))
        axis = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
        c2 = np.array([0.0, base_y - h2 / 2, 0.0]) + side * (lx / 2 + gap + s2 / 2) * axis
        prims.append(Box(tuple(map(float, c2)), (s2 / 2, h2 / 2, s2 / 2), "cardboard", "other-box", yaw_rad=yaw))
    aim = top_centre.copy()
    if var == "cut":  # aim beside the box so that the image border crosses its top
        right = np.array([1.0, 0.0, 0.0])
        aim = aim + right * float(rng.choice([-1.0, 1.0])) * (width / 2 / cam.fx * r * rng.uniform(0.85, 1.05))
    pose = _look(aim, r, down)
    params = SceneParams(scene="boxes", distance_m=max(0.8, r), width=width, height=height, texture_seed=int(seed % 97))
    spec = SceneSpec(tuple(prims), {}, 0.0)
    view, frame = _sensed(params, spec, pose, profile, lighting, np.random.default_rng([seed, 1]))
    corners = box.corners()
    top = corners[corners[:, 1] < base_y - h + 1e-9]  # the four at the top (Y up is negative)
    ang = np.arctan2(top[:, 2], top[:, 0])
    top = top[np.argsort(ang)]
    cpx = _project(pose, frame, top)
    edge = [float(np.linalg.norm(top[1] - top[0])), float(np.linalg.norm(top[2] - top[1]))]
    shown, total = _top_pixels(view, cpx, width, height)
    visible = float(shown.sum()) / total if total else 0.0
    centre_px = _project(pose, frame, top_centre[None])[0]
    # A person clicks the top where it shows: where its centre is hidden (by the box beside it) or
    # outside the image, at its shown pixel nearest the centre.
    ci, cj = int(round(centre_px[1])), int(round(centre_px[0]))
    if shown.any() and not (0 <= ci < height and 0 <= cj < width and shown[ci, cj]):
        ys, xs = np.nonzero(shown)
        k = int(np.argmin((xs - centre_px[0]) ** 2 + (ys - centre_px[1]) ** 2))
        centre_px = np.array([float(xs[k]), float(ys[k])])
    click = centre_px + rng.normal(0.0, CLICK_SIGMA_PX, 2)
    click = (float(np.clip(round(click[0]), 0, width - 1)), float(np.clip(round(click[1]), 0, height - 1)))
    # A region of the supporting surface in front of the box: a small square below its nearest corner.
    near = top[np.argmin(top[:, 2])]
    front = near + np.array([0.0, h, -0.12])
    sq = np.array([front + np.array([dx, 0.0, dz]) for dx, dz in ((-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05))])
    base_px = tuple(tuple(map(float, p)) for p in _project(pose, frame, sq))
    up = pose.R.T @ np.array([0.0, -1.0, 0.0])  # world Y points down
    offset = -float(up @ pose.to_camera(np.array([0.0, base_y, 0.0])))
    return BoxCase(frame, click, max(edge), min(edge), h, tuple(tuple(map(float, p)) for p in cpx), visible, var,
                   support, r, base_px, (*map(float, up), offset))


def _top_pixels(view, cpx: np.ndarray, width: int, height: int) -> tuple[np.ndarray, int]:
    """The top face's pixels that are in the image and show the box (H x W bool), and the pixel count
    of its whole projected polygon (in the image or not)."""
    import cv2

    if not np.isfinite(cpx).all():
        return np.zeros((height, width), bool), 0
    pad = max(width, height)
    canvas = np.zeros((height + 2 * pad, width + 2 * pad), np.uint8)
    cv2.fillPoly(canvas, [np.round(cpx + pad).astype(np.int32).reshape(-1, 1, 2)], 1)
    total = int(canvas.sum())
    inside = canvas[pad:pad + height, pad:pad + width].astype(bool)
    box_id = view.objects.index("box")
    return inside & (view.obj == box_id), total


def panel_case(seed: int, profile: str = "stress", lighting: str = "indoor", range_m: float | None = None,
               width: int = 1280, height: int = 720) -> PanelCase:
    """A framed panel on a wall seen from ``range_m`` (0.6-3 m) at a yaw of up to 30 degrees, clicked at its corners."""
    rng = np.random.default_rng([seed, 0xA4EA])
    r = float(rng.uniform(0.6, 3.0)) if range_m is None else float(range_m)
    cam = reference_camera(width, height)
    yaw = math.radians(float(rng.uniform(-30.0, 30.0)))
    fit = 0.75 * height / cam.fy * r * math.cos(yaw)
    pw, ph = float(rng.uniform(0.15, max(0.2, min(1.2, fit)))), float(rng.uniform(0.15, max(0.2, min(1.2, fit))))
    centre = np.array([0.0, -1.2, 0.0])
    u = np.array([math.cos(yaw), 0.0, -math.sin(yaw)])
    v = np.array([0.0, 1.0, 0.0])
    n = np.cross(u, v)
    wall = Rect(tuple(map(float, centre + 0.02 * np.sign(n[2]) * n)), tuple(map(float, u)), (0.0, 1.0, 0.0), (6.0, 3.0), "paint", "wall")
    panel = Rect(tuple(map(float, centre)), tuple(map(float, u)), (0.0, 1.0, 0.0), (pw / 2, ph / 2), "wallpaper", "panel")
    floor = Rect((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (40.0, 40.0), "wood", "floor")
    pose = _look(centre, r, float(rng.uniform(0.0, 15.0)))
    params = SceneParams(scene="poster", distance_m=max(0.8, r), width=width, height=height, texture_seed=int(seed % 97))
    _, frame = _sensed(params, SceneSpec((floor, wall, panel), {}, 0.0), pose, profile, lighting, np.random.default_rng([seed, 2]))
    corners = np.array([centre + a * pw / 2 * u + b * ph / 2 * v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    cpx = _project(pose, frame, corners) + rng.normal(0.0, CLICK_SIGMA_PX, (4, 2))
    cpx = np.clip(np.round(cpx), 0, [width - 1, height - 1])
    return PanelCase(frame, tuple(tuple(map(float, p)) for p in cpx), pw * ph, r)
