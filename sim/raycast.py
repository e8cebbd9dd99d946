"""Vectorised ray casting of analytic primitives (rectangles, boxes, capsules) from a pinhole camera.

World frame: X right, Y down, Z forward (metres), the same handedness as the OpenCV camera frame.
Every pixel's ray is ``C + t * R @ ((u - cx) / fx, (v - cy) / fy, 1)``; with that scaling ``t`` is the
depth Z of the hit in the camera frame, which is exactly what a range camera reports.
Each primitive only intersects the rays inside its projected bounding rectangle, so small objects
(a person, a box) cost little at 1280x720.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure import PinholeCamera

_EPS = 1e-9


@dataclass(frozen=True)
class Pose:
    """Camera centre ``centre`` (world, m) and rotation ``rotation`` (3x3, columns = camera axes in world)."""

    centre: tuple[float, float, float]
    rotation: tuple[tuple[float, float, float], ...]

    @property
    def R(self) -> np.ndarray:
        return np.asarray(self.rotation, dtype=np.float64)

    @property
    def C(self) -> np.ndarray:
        return np.asarray(self.centre, dtype=np.float64)

    @staticmethod
    def looking(centre: tuple[float, float, float], pitch_rad: float = 0.0) -> Pose:
        """A camera at ``centre`` looking along +Z, pitched down by ``pitch_rad`` (about the X axis)."""
        s, c = np.sin(pitch_rad), np.cos(pitch_rad)
        x, y, z = (1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c)
        rot = tuple(tuple(float(v) for v in row) for row in np.array([x, y, z]).T)
        return Pose(centre=tuple(float(v) for v in centre), rotation=rot)

    def shifted(self, dx_cam: float) -> Pose:
        """The same orientation, moved ``dx_cam`` metres along the camera's own X axis (a stereo partner)."""
        centre = self.C + dx_cam * self.R[:, 0]
        return Pose(centre=tuple(float(v) for v in centre), rotation=self.rotation)

    def to_camera(self, p_world: np.ndarray) -> np.ndarray:
        return (np.asarray(p_world, dtype=np.float64) - self.C) @ self.R

    def project(self, camera: PinholeCamera, p_world: np.ndarray) -> np.ndarray:
        """Pixel coordinates (..., 2) of world points; NaN behind the camera."""
        pc = self.to_camera(p_world)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = camera.fx * pc[..., 0] / z + camera.cx
            v = camera.fy * pc[..., 1] / z + camera.cy
        out = np.stack([u, v], axis=-1)
        out[z <= 1e-3] = np.nan
        return out


@dataclass(frozen=True)
class Rect:
    """A bounded plane: centre, unit in-plane axes ``u`` and ``v``, half sizes (m). Texture coords (s, r) in m."""

    centre: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]
    half: tuple[float, float]
    material: str
    obj: str

    def corners(self) -> np.ndarray:
        c, u, v = (np.asarray(a, dtype=np.float64) for a in (self.centre, self.u, self.v))
        a, b = self.half
        return np.array([c + su * a * u + sv * b * v for su in (-1, 1) for sv in (-1, 1)])

    def intersect(self, o: np.ndarray, D: np.ndarray) -> np.ndarray:
        c, u, v = (np.asarray(a, dtype=np.float64) for a in (self.centre, self.u, self.v))
        n = np.cross(u, v)
        oc = o - c
        # Rays parallel to the plane (the horizon row of a level camera) give inf/NaN: no hit.
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -(oc @ n) / (D @ n)
            s = oc @ u + t * (D @ u)
            r = oc @ v + t * (D @ v)
            inside = (np.abs(s) <= self.half[0]) & (np.abs(r) <= self.half[1]) & (t > _EPS)
        return np.where(inside, t, np.inf)

    def surface(self, P: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, u, v = (np.asarray(a, dtype=np.float64) for a in (self.centre, self.u, self.v))
        n = np.cross(u, v)
        if (o - c) @ n < 0:  # one camera centre sees one side of a plane: face it
            n = -n
        q = P - c
        return n, np.stack([q @ u, q @ v]).T  # N x 2, each coordinate contiguous (what the textures read)


@dataclass(frozen=True)
class Box:
    """A box standing upright: centre, yaw about the vertical (world Y) axis, half extents (m)."""

    centre: tuple[float, float, float]
    half: tuple[float, float, float]
    material: str
    obj: str
    yaw_rad: float = 0.0

    def _axes(self) -> np.ndarray:
        s, c = np.sin(self.yaw_rad), np.cos(self.yaw_rad)
        return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # rows: local x, y, z in world

    def corners(self) -> np.ndarray:
        A, h = self._axes(), np.asarray(self.half)
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)
        return np.asarray(self.centre) + (signs * h) @ A

    def intersect(self, o: np.ndarray, D: np.ndarray) -> np.ndarray:
        A, h = self._axes(), np.asarray(self.half)
        ol = A @ (o - np.asarray(self.centre))
        Dl = D @ A.T
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / Dl
            t1 = (-h - ol) * inv
            t2 = (h - ol) * inv
        tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
        tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
        hit = (tmax >= tmin) & (tmin > _EPS)
        return np.where(hit, tmin, np.inf)

    def surface(self, P: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        A, h = self._axes(), np.asarray(self.half)
        q = (P - np.asarray(self.centre)) @ A.T
        rel = np.abs(q) / h
        axis = np.argmax(rel, axis=-1)
        nl = np.zeros_like(q)
        np.put_along_axis(nl, axis[..., None], np.sign(np.take_along_axis(q, axis[..., None], -1)), -1)
        # Texture coords: the two in-plane local coordinates of the face that was hit.
        s = np.where(axis == 0, q[..., 2], q[..., 0])
        r = np.where(axis == 1, q[..., 2], q[..., 1])
        return nl @ A, np.stack([s, r]).T


@dataclass(frozen=True)
class Capsule:
    """A capsule (segment a-b swept by radius r, m); a == b makes a sphere. Texture coords are world (X, Y)."""

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float
    material: str
    obj: str

    def corners(self) -> np.ndarray:
        a, b, r = np.asarray(self.a), np.asarray(self.b), self.radius
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64)
        lo, hi = np.minimum(a, b) - r, np.maximum(a, b) + r
        return (lo + hi) / 2 + signs * (hi - lo) / 2

    def intersect(self, o: np.ndarray, D: np.ndarray) -> np.ndarray:
        # Inigo Quilez's analytic ray-capsule intersection, on unit directions.
        norm = np.linalg.norm(D, axis=-1)
        rd = D / norm[..., None]
        pa, pb, ra = np.asarray(self.a), np.asarray(self.b), self.radius
        ba, oa = pb - pa, o - pa
        baba, baoa, oaoa = ba @ ba, ba @ oa, oa @ oa
        bard, rdoa = rd @ ba, rd @ oa
        t = np.full(norm.shape, np.inf)
        with np.errstate(invalid="ignore", divide="ignore"):
            if baba > _EPS:
                a = baba - bard * bard
                b = baba * rdoa - baoa * bard
                c = baba * oaoa - baoa * baoa - ra * ra * baba
                h = b * b - a * c
                tb = (-b - np.sqrt(h)) / a
                y = baoa + tb * bard
                body = (h >= 0) & (y > 0) & (y < baba)
                t = np.where(body, tb, t)
                cap_b = y >= baba
                oc_rd = np.where(cap_b, rd @ (o - pb), rdoa)
                oc_oc = np.where(cap_b, (o - pb) @ (o - pb), oaoa)
            else:
                body = np.zeros(norm.shape, bool)
                h = np.ones(norm.shape)
                oc_rd, oc_oc = rdoa, np.full(norm.shape, oaoa)
            hc = oc_rd * oc_rd - (oc_oc - ra * ra)
            tc = -oc_rd - np.sqrt(hc)
            caps = (~body) & (h >= 0) & (hc > 0)
            t = np.where(caps, tc, t)
        t = np.where(t > _EPS, t / norm, np.inf)
        return t

    def surface(self, P: np.ndarray, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pa, pb = np.asarray(self.a), np.asarray(self.b)
        ba = pb - pa
        baba = max(ba @ ba, _EPS)
        hpar = np.clip(((P - pa) @ ba) / baba, 0.0, 1.0)
        n = P - (pa + hpar[..., None] * ba)
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), _EPS)
        return n, P[..., :2].copy()


Primitive = Rect | Box | Capsule


@dataclass(frozen=True)
class Surface:
    """The pixels one primitive is nearest at: flat pixel indices, texture coords (N x 2, m), normals
    (N x 3, or one 3-vector for a plane), all facing the camera."""

    prim: Primitive
    index: np.ndarray
    uv: np.ndarray
    normals: np.ndarray


@dataclass(frozen=True)
class Hits:
    """Nearest hit per pixel: depth Z (m, inf = nothing), primitive index (-1 = none), visible surfaces."""

    depth: np.ndarray
    prim: np.ndarray
    surfaces: tuple[Surface, ...]


def pixel_rays(camera: PinholeCamera, pose: Pose) -> np.ndarray:
    """World directions (H x W x 3) scaled so that ``t`` along them is the camera-frame depth."""
    u = (np.arange(camera.width, dtype=np.float64) - camera.cx) / camera.fx
    v = (np.arange(camera.height, dtype=np.float64) - camera.cy) / camera.fy
    d = np.empty((camera.height, camera.width, 3))
    d[..., 0] = u[None, :]
    d[..., 1] = v[:, None]
    d[..., 2] = 1.0
    return d @ pose.R.T


def _screen_box(prim: Primitive, camera: PinholeCamera, pose: Pose, margin: int = 2) -> tuple[slice, slice]:
    """The pixel rows and columns a primitive can be hit at: the bounding box (plus ``margin`` px) of its
    corners' hull clipped to the part in front of the camera (depth >= ``_EPS``, as every hit is), so a floor
    that runs on behind the camera is looked for below the horizon only, not in every pixel."""
    z_near = _EPS
    pc = pose.to_camera(prim.corners())
    front, behind = pc[pc[:, 2] >= z_near], pc[pc[:, 2] < z_near]
    if not len(front):
        return slice(0, 0), slice(0, 0)
    # where the hull meets the plane z = z_near: on the segments from each corner in front to each behind
    a, b = np.repeat(front, len(behind), axis=0), np.tile(behind, (len(front), 1))
    f = (a[:, 2] - z_near) / (a[:, 2] - b[:, 2])
    pts = np.concatenate([front, a + f[:, None] * (b - a)])
    with np.errstate(over="ignore"):
        u = camera.fx * pts[:, 0] / np.maximum(pts[:, 2], z_near) + camera.cx
        v = camera.fy * pts[:, 1] / np.maximum(pts[:, 2], z_near) + camera.cy
    x0 = int(np.clip(np.floor(u.min()) - margin, 0, camera.width))
    x1 = int(np.clip(np.ceil(u.max()) + margin + 1, 0, camera.width))
    y0 = int(np.clip(np.floor(v.min()) - margin, 0, camera.height))
    y1 = int(np.clip(np.ceil(v.max()) + margin + 1, 0, camera.height))
    return slice(y0, y1), slice(x0, x1)


def cast(prims: tuple[Primitive, ...], camera: PinholeCamera, pose: Pose) -> Hits:
    """Nearest intersection of every pixel's ray with the primitives (culled to each one's screen box)."""
    D = pixel_rays(camera, pose)
    o = pose.C
    depth = np.full((camera.height, camera.width), np.inf)
    prim = np.full((camera.height, camera.width), -1, dtype=np.int16)
    boxes = [_screen_box(p, camera, pose) for p in prims]
    for i, (p, (sy, sx)) in enumerate(zip(prims, boxes)):
        if sy.stop <= sy.start or sx.stop <= sx.start:
            continue
        t = p.intersect(o, D[sy, sx])
        closer = t < depth[sy, sx]
        np.copyto(depth[sy, sx], t, where=closer)
        np.copyto(prim[sy, sx], i, where=closer)
    surfaces = []
    flat_depth, flat_D = depth.ravel(), D.reshape(-1, 3)
    for i, (p, (sy, sx)) in enumerate(zip(prims, boxes)):
        # a primitive is nearest only inside its own box: look there (np.nonzero keeps the image's row-major order)
        rows, cols = np.nonzero(prim[sy, sx] == i)
        if rows.size:
            idx = (rows + sy.start) * camera.width + (cols + sx.start)
            P = flat_D.take(idx, axis=0)  # the hit point C + t D, t the depth along the scaled ray
            P *= flat_depth.take(idx)[:, None]
            P += o
            normals, uv = p.surface(P, o)
            surfaces.append(Surface(p, idx, uv, normals))
    return Hits(depth=depth, prim=prim, surfaces=tuple(surfaces))
