"""Analytic scenes of the simulated rig, ray-cast from the reference camera, with their measurable targets.

World frame: floor at Y = 0, Y down (heights are negative Y), Z away from the camera, metres. The
reference camera stands at ``CAMERA_HEIGHT_M`` above the floor directly over the world origin and is
pitched so that the measured target sits in the middle of the image. Distances are those of the
target's front surface from the camera, along Z (the paper's 2, 4, 6 and 7 m, or anything between).

The poster is the paper's "oriented target board" (Figures 1-2): by default a rigid board on two thin
legs, standing ``standoff_m`` in front of the wall at any yaw and roll, so its whole outline is a depth
edge (where the sensor model puts its contended band and edge fattening, and where a tap just off
the board meets the wall behind). ``mount="wall"`` keeps the older poster glued flat on the wall.
The "charuco" scene stands a printed ChArUco board the same way (OpenCV's own board image,
``SceneParams.charuco``; sim/charuco.py), so its corners' 3D positions are known exactly and
`depthruler check` runs end to end on the simulator.

A :class:`View` caches one ray-cast (depth, object ids) and its colour render under each lighting
preset, shaded the first time that preset is asked for, per (scene, pose, image size), so a new frame
only costs the sensor noise.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from measure import PinholeCamera

from sim.raycast import Box, Capsule, Pose, Primitive, Rect, Surface, cast
from sim.shading import Painted, Renders
from sim.textures import pattern
from sim.truth import Truth

CAMERA_HEIGHT_M = 1.4
REFERENCE_FX_AT_1280 = 1000.0  # focal length (px) of the reference camera at 1280 px long side: 65 deg HFOV

SCENES: tuple[str, ...] = ("poster", "person", "doorway", "boxes", "table", "charuco", "plain-wall")
TARGETS: dict[str, tuple[str, ...]] = {  # the first one is the scene's default target
    "poster": ("poster-width", "poster-length", "poster-width-upper", "poster-width-lower", "poster-length-left",
               "poster-length-right"),
    "person": ("person-height",),
    "doorway": ("doorway",),
    "boxes": ("box-gap", "box-width"),
    "table": ("table-width",),
    "charuco": ("board-width", "board-height"),
    "plain-wall": ("wall-width", "poster-width"),
}


class SceneError(ValueError):
    """A scene cannot be built or viewed as asked; the message says which parameter to change."""


MOUNTS: tuple[str, ...] = ("stand", "wall")
# The paper's target (Figures 1-2, "an oriented target board", errors "along the boundaries of the
# target (especially at the bottom edge)") is a board standing free, with depth edges all round. Its
# size is not published: A0 portrait (841 x 1189 mm) is an assumption, a common size for a printed
# measurement board that still fits a 1280x720 frame at 2 m (595 px tall).
BOARD_M: tuple[float, float] = (0.841, 1.189)
# The ChArUco board of the "charuco" scene when none is named: (squares across, down, square m, marker m,
# dictionary), the board `depthruler check` is documented with (sim/charuco.py).
CHARUCO_BOARD: tuple[int, int, float, float, str] = (7, 5, 0.040, 0.030, "DICT_5X5_100")
# How far a free-standing board is in front of the wall (m); scenario() draws one per seed.
STANDOFFS_M: tuple[float, ...] = (0.5, 1.0, 1.5)


@dataclass(frozen=True)
class SceneParams:
    """What to build: scene name, target distance (m), yaw of the target about the vertical (deg),
    in-plane roll of the poster (deg), image size (px), the texture seed, and for the poster: how it is
    mounted ("stand": a rigid board on two thin legs, ``standoff_m`` in front of the wall, so its whole
    outline is a depth edge; "wall": glued flat on the wall, no depth edge), its width and length (m)."""

    scene: str = "poster"
    distance_m: float = 4.0
    yaw_deg: float = 0.0
    roll_deg: float = 0.0
    width: int = 1280
    height: int = 720
    texture_seed: int = 0
    mount: str = "stand"
    board_w_m: float = BOARD_M[0]
    board_l_m: float = BOARD_M[1]
    standoff_m: float = 1.0
    charuco: tuple[int, int, float, float, str] = CHARUCO_BOARD  # scene "charuco": the printed board

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise SceneError(f"unknown scene {self.scene!r}; use one of {', '.join(SCENES)}")
        if not (0.8 <= self.distance_m <= 20.0):
            raise SceneError(f"distance_m={self.distance_m} is out of range; use 0.8 to 20 m (the paper: 2, 4, 6, 7)")
        if not (-60.0 <= self.yaw_deg <= 60.0):
            raise SceneError(f"yaw_deg={self.yaw_deg} is out of range; use -60 to 60 degrees")
        if not (16 <= self.width <= 4096 and 16 <= self.height <= 4096):
            raise SceneError(f"image size {self.width}x{self.height} is out of range; use 16..4096 px per side")
        if self.mount not in MOUNTS:
            raise SceneError(f"mount={self.mount!r} is unknown; use one of {', '.join(MOUNTS)}")
        if not (0.05 <= self.board_w_m <= 3.0 and 0.05 <= self.board_l_m <= 3.0):
            raise SceneError(f"board size {self.board_w_m} x {self.board_l_m} m is out of range; use 0.05 to 3 m per side")
        if not (0.1 <= self.standoff_m <= 5.0):
            raise SceneError(f"standoff_m={self.standoff_m} is out of range; use 0.1 to 5 m in front of the wall")
        sx, sy, square, marker, _ = self.charuco
        if not (sx >= 3 and sy >= 3 and 0 < marker < square and sx * square <= 3.0 and sy * square <= 3.0):
            raise SceneError(f"ChArUco board {sx}x{sy} squares of {square} m, markers {marker} m: use at least 3x3 "
                             "squares, markers smaller than squares, at most 3 m per side")


@dataclass(frozen=True)
class TargetSpec:
    """A measurable length: true world end points, the object(s) each end lies on, and whether it is a gap."""

    name: str
    e1: tuple[float, float, float]
    e2: tuple[float, float, float]
    objs1: tuple[str, ...]
    objs2: tuple[str, ...]
    is_gap: bool


@dataclass(frozen=True)
class SceneSpec:
    prims: tuple[Primitive, ...]
    targets: dict[str, TargetSpec]
    aim_height_m: float


def reference_camera(width: int, height: int) -> PinholeCamera:
    """The reference (colour) camera: square pixels, fx = 1000 px at a 1280 px long side, centred."""
    f = REFERENCE_FX_AT_1280 * max(width, height) / 1280.0
    return PinholeCamera(fx=f, fy=f, cx=(width - 1) / 2.0, cy=(height - 1) / 2.0, width=width, height=height)


class _Placer:
    """Maps a target's local coordinates (x right, h up, z back) into the world: yaw about the vertical
    axis through (0, *, distance)."""

    def __init__(self, distance: float, yaw_deg: float) -> None:
        self.d = distance
        s, c = math.sin(math.radians(yaw_deg)), math.cos(math.radians(yaw_deg))
        self.lx = np.array([c, 0.0, -s])
        self.lz = np.array([s, 0.0, c])
        self.yaw = math.radians(yaw_deg)

    def __call__(self, x: float, h: float, z: float = 0.0) -> tuple[float, float, float]:
        p = np.array([0.0, -h, self.d]) + x * self.lx + z * self.lz
        return (float(p[0]), float(p[1]), float(p[2]))

    def vec(self, v: np.ndarray) -> tuple[float, float, float]:
        return tuple(float(a) for a in v)  # type: ignore[return-value]


def _floor() -> Rect:
    return Rect((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (40.0, 40.0), "wood", "floor")


def _wall(place: _Placer, z: float, material: str = "paint", obj: str = "wall", half_width: float = 10.0) -> Rect:
    down = np.array([0.0, 1.0, 0.0])
    return Rect(place(0.0, 2.5, z), place.vec(place.lx), place.vec(down), (half_width, 2.5), material, obj)


def _poster(p: SceneParams) -> SceneSpec:
    prims, c, u, v = _printed_board(p, p.board_w_m, p.board_l_m, "poster", "poster")
    w, l = p.board_w_m, p.board_l_m
    place = _Placer(p.distance_m, p.yaw_deg)

    def across(name: str, mid: np.ndarray, half: np.ndarray) -> TargetSpec:
        return TargetSpec(name, place.vec(mid - half), place.vec(mid + half), ("poster",), ("poster",), False)

    # The paper measured each dimension three times "by clicking on different points on the target"
    # (Fig. 1: 3 lengths, 3 widths): through the centre and a quarter of the board either side.
    targets = {}
    for tag, f in (("", 0.0), ("-upper", -0.25), ("-lower", 0.25)):  # v runs down the board
        targets["poster-width" + tag] = across("poster-width" + tag, c + f * l * v, w / 2 * u)
    for tag, f in (("", 0.0), ("-left", -0.25), ("-right", 0.25)):
        targets["poster-length" + tag] = across("poster-length" + tag, c + f * w * u, l / 2 * v)
    return SceneSpec(prims, targets, CAMERA_HEIGHT_M)


def charuco_sheet_m(board: tuple[int, int, float, float, str]) -> tuple[float, float, float]:
    """Sheet width, height and white margin (m) of a printed ChArUco board: the squares plus a margin of
    half a square all round (the quiet zone the detector needs against the wall behind)."""
    sx, sy, square = board[0], board[1], board[2]
    margin = square / 2
    return sx * square + 2 * margin, sy * square + 2 * margin, margin


def charuco_corner_offsets(board: tuple[int, int, float, float, str]) -> np.ndarray:
    """In-plane offsets (K x 2, m, along the sheet's u right and v down, from the sheet centre) of the
    board's chessboard corners in OpenCV's id order (row by row from the top left), K = (sx-1)(sy-1)."""
    sx, sy, square = board[0], board[1], board[2]
    i, j = np.meshgrid(np.arange(1, sx), np.arange(1, sy))
    return np.stack([i.ravel() * square - sx * square / 2, j.ravel() * square - sy * square / 2], axis=1)


def _charuco(p: SceneParams) -> SceneSpec:
    w, l, _ = charuco_sheet_m(p.charuco)
    prims, c, u, v = _printed_board(p, w, l, "charuco", "board")
    place = _Placer(p.distance_m, p.yaw_deg)
    k = charuco_corner_offsets(p.charuco)
    sx = p.charuco[0]
    world = lambda a: place.vec(c + a[0] * u + a[1] * v)  # noqa: E731
    targets = {  # the outer corners of the top row and of the left column
        "board-width": TargetSpec("board-width", world(k[0]), world(k[sx - 2]), ("board",), ("board",), False),
        "board-height": TargetSpec("board-height", world(k[0]), world(k[-(sx - 1)]), ("board",), ("board",), False),
    }
    return SceneSpec(prims, targets, CAMERA_HEIGHT_M)


def board_frame(p: SceneParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World centre and unit axes u (right), v (down) of the printed board of a poster or charuco scene."""
    w, l = charuco_sheet_m(p.charuco)[:2] if p.scene == "charuco" else (p.board_w_m, p.board_l_m)
    _, c, u, v = _printed_board(p, w, l, "", "")
    return c, u, v


def _printed_board(p: SceneParams, w: float, l: float, material: str, obj: str
                   ) -> tuple[tuple[Primitive, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Floor, wall (and legs) and a printed board of w x l m: the primitives, the board centre and axes."""
    place = _Placer(p.distance_m, p.yaw_deg)
    ly = np.array([0.0, 1.0, 0.0])
    r = math.radians(p.roll_deg)
    u = math.cos(r) * place.lx + math.sin(r) * ly
    v = -math.sin(r) * place.lx + math.cos(r) * ly  # down the board's length
    c = np.array(place(0.0, CAMERA_HEIGHT_M))
    if p.mount == "wall":
        c = c - 0.002 * place.lz  # 2 mm proud of the wall
        background: tuple[Primitive, ...] = (_wall(place, 0.0),)
    else:
        # The wall stays square to the camera; a turned board keeps clear of it by at least 10 cm.
        reach = max(abs((su * w / 2 * u + sv * l / 2 * v)[2]) for su in (-1, 1) for sv in (-1, 1))
        legs = tuple(
            Capsule(place.vec(top), (float(top[0]), 0.0, float(top[2])), 0.015, "shoe", "stand")
            for top in (c + sx * w / 4 * u + l / 4 * v + 0.03 * place.lz for sx in (-1, 1))
        )  # behind the board, down to the floor: only their lower part shows, under the bottom edge
        background = (_wall(_Placer(p.distance_m, 0.0), max(p.standoff_m, reach + 0.1)), *legs)
    board = Rect(place.vec(c), place.vec(u), place.vec(v), (w / 2, l / 2), material, obj)
    return (_floor(), *background, board), c, u, v


def _person(p: SceneParams, height_m: float = 1.75) -> SceneSpec:
    place = _Placer(p.distance_m, p.yaw_deg)
    s = height_m / 1.75
    cap = lambda x0, h0, x1, h1, r, mat: Capsule(place(x0 * s, h0 * s), place(x1 * s, h1 * s), r * s, mat, "person")  # noqa: E731
    prims: list[Primitive] = [
        _floor(),
        _wall(_Placer(p.distance_m, 0.0), 1.0),
        cap(-0.10, 0.075, -0.10, 0.85, 0.075, "jeans"),
        cap(0.10, 0.075, 0.10, 0.85, 0.075, "jeans"),
        Box(place(0.0, 1.15 * s), (0.19 * s, 0.30 * s, 0.11 * s), "shirt", "person", yaw_rad=place.yaw),
        cap(-0.25, 1.40, -0.30, 0.85, 0.05, "shirt"),
        cap(0.25, 1.40, 0.30, 0.85, 0.05, "shirt"),
        cap(0.0, 1.45, 0.0, 1.55, 0.05, "skin"),
        cap(0.0, 1.64, 0.0, 1.64, 0.11, "skin"),
    ]
    for x in (-0.10, 0.10):  # shoes: their front bottom edges stand on the floor, where people click
        prims.append(Box(place(x * s, 0.035 * s, -0.06 * s), (0.05 * s, 0.035 * s, 0.13 * s), "shoe", "person", yaw_rad=place.yaw))
    targets = {
        "person-height": TargetSpec(
            "person-height", place(0.0, height_m), place(-0.10 * s, 0.0, -0.19 * s), ("person",), ("person",), False
        )
    }
    return SceneSpec(tuple(prims), targets, height_m / 2)


def _doorway(p: SceneParams, width_m: float = 0.9, height_m: float = 2.05) -> SceneSpec:
    place = _Placer(p.distance_m, p.yaw_deg)
    down = place.vec(np.array([0.0, 1.0, 0.0]))
    lx = place.vec(place.lx)
    half = width_m / 2
    prims = (
        _floor(),
        Rect(place(-(half + 4.0), 2.5), lx, down, (4.0, 2.5), "paint", "wall"),
        Rect(place(half + 4.0, 2.5), lx, down, (4.0, 2.5), "paint", "wall"),
        Rect(place(0.0, (height_m + 5.0) / 2), lx, down, (half, (5.0 - height_m) / 2), "paint", "wall"),
        _wall(place, 3.0, "wallpaper", "back-wall", 12.0),
    )
    targets = {"doorway": TargetSpec("doorway", place(-half, 1.2), place(half, 1.2), ("wall",), ("wall",), True)}
    return SceneSpec(prims, targets, 1.2)


def _boxes(p: SceneParams, size=(0.5, 0.6, 0.4), gap_m: float = 0.6) -> SceneSpec:
    place = _Placer(p.distance_m, p.yaw_deg)
    w, h, d = size
    off = gap_m / 2 + w / 2
    prims = (
        _floor(),
        _wall(_Placer(p.distance_m, 0.0), 2.0),
        Box(place(-off, h / 2, d / 2), (w / 2, h / 2, d / 2), "cardboard", "box-left", yaw_rad=place.yaw),
        Box(place(off, h / 2, d / 2), (w / 2, h / 2, d / 2), "cardboard", "box-right", yaw_rad=place.yaw),
    )
    g = gap_m / 2
    targets = {
        "box-gap": TargetSpec("box-gap", place(-g, h / 2), place(g, h / 2), ("box-left",), ("box-right",), True),
        "box-width": TargetSpec("box-width", place(-g - w, h / 2), place(-g, h / 2), ("box-left",), ("box-left",), False),
    }
    return SceneSpec(prims, targets, h / 2)


def _table(p: SceneParams, top=(1.2, 0.75), height_m: float = 0.75, thickness_m: float = 0.04) -> SceneSpec:
    place = _Placer(p.distance_m, p.yaw_deg)
    tw, td = top
    leg_h = height_m - thickness_m
    prims: list[Primitive] = [
        _floor(),
        _wall(_Placer(p.distance_m, 0.0), 1.5),
        Box(place(0.0, height_m - thickness_m / 2, td / 2), (tw / 2, thickness_m / 2, td / 2), "wood", "table", yaw_rad=place.yaw),
    ]
    for x in (-(tw / 2 - 0.05), tw / 2 - 0.05):
        for z in (0.05, td - 0.05):
            prims.append(Box(place(x, leg_h / 2, z), (0.025, leg_h / 2, 0.025), "wood", "table", yaw_rad=place.yaw))
    hm = height_m - thickness_m / 2
    targets = {"table-width": TargetSpec("table-width", place(-tw / 2, hm), place(tw / 2, hm), ("table",), ("table",), False)}
    return SceneSpec(tuple(prims), targets, height_m)


def _plain_wall(p: SceneParams) -> SceneSpec:
    """A plain painted wall (``paint``: grain far below the image noise, what passive stereo cannot match)
    filling the view, with a printed poster glued flat on it left of centre. Targets: a horizontal
    stretch of the plain wall right of the poster at the poster's centre height, and the poster's
    width. Rendered as a stereo pair (``mode=stereo``) it runs through the real SGBM path."""
    place = _Placer(p.distance_m, p.yaw_deg)
    w, l = p.board_w_m, p.board_l_m
    centre = np.array(place(-0.55 - w / 2, CAMERA_HEIGHT_M)) - 0.002 * place.lz  # 2 mm proud of the wall
    down = np.array([0.0, 1.0, 0.0])
    poster = Rect(place.vec(centre), place.vec(place.lx), place.vec(down), (w / 2, l / 2), "poster", "poster")
    wall_y = CAMERA_HEIGHT_M
    targets = {
        "wall-width": TargetSpec("wall-width", place(0.15, wall_y), place(0.15 + 0.8, wall_y), ("wall",), ("wall",), False),
        "poster-width": TargetSpec("poster-width", place.vec(centre - w / 2 * place.lx), place.vec(centre + w / 2 * place.lx),
                                   ("poster",), ("poster",), False),
    }
    return SceneSpec((_floor(), _wall(place, 0.0), poster), targets, CAMERA_HEIGHT_M)


_BUILDERS = {"poster": _poster, "person": _person, "doorway": _doorway, "boxes": _boxes, "table": _table,
             "charuco": _charuco, "plain-wall": _plain_wall}


def build_scene(params: SceneParams) -> SceneSpec:
    """The primitives and targets of a scene (world frame, metres)."""
    return _BUILDERS[params.scene](params)


def resolve_target(scene: str, target: str | None) -> str:
    """The full target name for ``scene`` ("width" or "poster-width" both work); None = the default."""
    allowed = TARGETS[scene]
    if target is None or target == "":
        return allowed[0]
    for name in allowed:
        if target in (name, name.split("-", 1)[-1]):
            return name
    raise SceneError(f"scene {scene!r} has no target {target!r}; use one of {', '.join(allowed)}")


@dataclass(frozen=True, eq=False)  # hashed by identity: views are cached and hold arrays
class View:
    """One ray-cast of a scene: camera, pose, depth (m, NaN = nothing hit), object ids, colour renders."""

    params: SceneParams
    camera: PinholeCamera
    pose: Pose
    depth: np.ndarray  # H x W float64, read-only
    obj: np.ndarray  # H x W int16 index into objects, -1 = nothing
    objects: tuple[str, ...]
    renders: Mapping[str, np.ndarray]  # lighting -> H x W x 3 uint8 BGR, read-only (Renders)
    spec: SceneSpec

    def truth(self, target: str | None = None) -> Truth:
        """Ground truth of ``target``: the surface points at the pixel centres nearest to the true end
        points that lie on the target's object (inward for objects, outward for gaps)."""
        name = resolve_target(self.params.scene, target)
        t = self.spec.targets[name]
        e = self.pose.project(self.camera, np.array([t.e1, t.e2]))
        if not np.all(np.isfinite(e)):
            raise SceneError(f"target {name} is behind the camera; increase distance_m")
        direction = (e[1] - e[0]) / max(float(np.linalg.norm(e[1] - e[0])), 1e-9)
        sign = -1.0 if t.is_gap else 1.0
        px1 = self._end_pixel(e[0], sign * direction, t.objs1, name)
        px2 = self._end_pixel(e[1], -sign * direction, t.objs2, name)
        p1, p2 = self._camera_point(px1), self._camera_point(px2)
        return Truth(
            depth_m=self.depth,
            p1_m=tuple(map(float, p1)),
            p2_m=tuple(map(float, p2)),
            p1_px=(float(px1[0]), float(px1[1])),
            p2_px=(float(px2[0]), float(px2[1])),
            length_m=float(np.linalg.norm(p1 - p2)),
            target=name,
            is_gap=t.is_gap,
        )

    def _end_pixel(self, start: np.ndarray, step: np.ndarray, objs: tuple[str, ...], name: str) -> tuple[int, int]:
        ids = [self.objects.index(o) for o in objs if o in self.objects]
        h, w = self.depth.shape
        margin = 2
        for k in range(0, 120):
            x, y = np.rint(start + 0.5 * k * step).astype(int)
            if margin <= x < w - margin and margin <= y < h - margin and self.obj[y, x] in ids:
                return int(x), int(y)
        raise SceneError(
            f"target {name} of scene {self.params.scene!r} is not fully visible in a {w}x{h} image at "
            f"{self.params.distance_m} m; move further away (larger distance) or use a portrait image "
            f"(width={min(w, h)}, height={max(w, h)})"
        )

    def _camera_point(self, px: tuple[int, int]) -> np.ndarray:
        # From the world hit point, independently of the depth map: tests then check the two agree.
        x, y = px
        cam = self.camera
        ray = self.pose.R @ np.array([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0])
        world = self.pose.C + self.depth[y, x] * ray
        return self.pose.to_camera(world)


def _charuco_pattern(surface: Surface, camera: PinholeCamera, pose: Pose, board: tuple) -> np.ndarray:
    from sim.charuco import board_pattern  # OpenCV's ArUco module, only for this scene

    return board_pattern(surface, camera, pose, board)


@lru_cache(maxsize=32)  # ~20 MB each at 1280x720
def get_view(params: SceneParams, shift_m: float = 0.0) -> View:
    """The cached ray-cast of ``params`` from the reference camera, or from a camera ``shift_m`` metres to
    its right (same orientation: a rectified stereo partner)."""
    spec = build_scene(params)
    camera = reference_camera(params.width, params.height)
    pitch = math.atan2(CAMERA_HEIGHT_M - spec.aim_height_m, params.distance_m)
    pose = Pose.looking((0.0, -CAMERA_HEIGHT_M, 0.0), pitch)
    if shift_m:
        pose = pose.shifted(shift_m)
    return make_view(params, spec, camera, pose)


def make_view(params: SceneParams, spec: SceneSpec, camera: PinholeCamera, pose: Pose) -> View:
    """Ray-cast ``spec``'s primitives from ``pose`` and paint their textures (not cached); each lighting
    preset is shaded when first asked for (:class:`Renders`)."""
    hits = cast(spec.prims, camera, pose)
    depth = np.where(np.isfinite(hits.depth), hits.depth, np.nan)
    objects = tuple(dict.fromkeys(p.obj for p in spec.prims))
    lut = np.array([objects.index(p.obj) for p in spec.prims] + [-1], np.int16)
    obj = lut[hits.prim]  # prim == -1 picks the trailing -1
    poster_mm = (int(round(params.board_w_m * 1000)), int(round(params.board_l_m * 1000)))  # print fills the board
    painted = tuple(
        Painted(s.prim.material, s.index.astype(np.int32), s.normals,
                 pattern(s.prim.material, s.uv, seed=params.texture_seed, poster_mm=poster_mm) if s.prim.material != "charuco"
                 else _charuco_pattern(s, camera, pose, params.charuco))
        for s in hits.surfaces
    )
    for a in (depth, obj):
        a.setflags(write=False)
    return View(params, camera, pose, depth, obj, objects, Renders(painted, depth.shape), spec)
