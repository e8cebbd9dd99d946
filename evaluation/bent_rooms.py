"""Bent segments (`evaluation/bent_rooms.py`): a wall, or a board standing in front of it, down to the floor.

Each room is analytic: a camera ``height`` m above the floor (1.2-1.6), pitched ``pitch`` degrees down
(3-15), a wall ``wall`` m ahead (2.5-5) and, for the "board" kind, a board 0.8-1.2 m tall standing
0.4-1.0 m in front of it. Disparity is fx B / Z with noise correlated over a few pixels, quantized to
``QUANTUM`` px; along the seam (where wall or board meets the floor) a band of ``SEAM_PX`` rows has half
of its pixels from the other surface (the contention of a three-camera rig at a crease). One click is
inside the wall (or board), the other on the floor in front, both at least ``INSIDE_PX`` from the seam;
truth from the analytic depth at the clicked pixels. Seeds draw every parameter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from evaluation.stress import StressCase, StressRecord, measure_case

QUANTUM = 0.25
SEAM_PX = 6
INSIDE_PX = 25
WIDTH, HEIGHT, FX, BASELINE = 640, 480, 500.0, 0.06
DEV_SEEDS: tuple[int, ...] = tuple(range(12))
HELD_OUT_SEEDS: tuple[int, ...] = tuple(range(1000, 1012))


@dataclass(frozen=True)
class Room:
    kind: str  # "wall" or "board"
    height_m: float
    pitch_deg: float
    wall_m: float
    board_m: tuple[float, float]  # (distance in front of the wall, height), board kind only


def _draw(kind: str, rng: np.random.Generator) -> Room:
    return Room(kind, float(rng.uniform(1.2, 1.6)), float(rng.uniform(3.0, 15.0)), float(rng.uniform(2.5, 5.0)),
                (float(rng.uniform(0.4, 1.0)), float(rng.uniform(0.8, 1.2))))


def room_depth(room: Room) -> tuple[np.ndarray, np.ndarray]:
    """Camera-Z depth (m) per pixel and the surface id (0 floor, 1 wall, 2 board; -1 nothing)."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    cx, cy = (WIDTH - 1) / 2, (HEIGHT - 1) / 2
    a = math.radians(room.pitch_deg)
    # Camera ray (x right, y down, z forward) rotated into the world (Y down, Z ahead), pitched down by a.
    rx, ry, rz = (xs - cx) / FX, (ys - cy) / FX, np.ones_like(xs)
    wy = ry * math.cos(a) + rz * math.sin(a)
    wz = -ry * math.sin(a) + rz * math.cos(a)
    hits = np.full((3,) + xs.shape, np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(wy > 0, room.height_m / wy, np.inf)
        hits[0] = t_floor
        hits[1] = np.where(wz > 0, room.wall_m / wz, np.inf)
        if room.kind == "board":
            zb = room.wall_m - room.board_m[0]
            tb = np.where(wz > 0, zb / wz, np.inf)
            y_at = tb * wy  # below the camera (m), positive down
            on = (y_at <= room.height_m) & (y_at >= room.height_m - room.board_m[1]) & (np.abs(tb * rx) <= 0.6)
            hits[2] = np.where(on, tb, np.inf)
    surface = np.argmin(hits, axis=0)
    t = np.take_along_axis(hits, surface[None], 0)[0]
    surface = np.where(np.isfinite(t), surface, -1)
    return t, surface  # rz = 1: the ray parameter is the camera-Z depth


def room_frame(room: Room, rng: np.random.Generator):
    """The measure.Frame of ``room`` (module docstring) and its true depth (m)."""
    import cv2

    from measure import Frame, PinholeCamera

    z, surface = room_depth(room)
    d = FX * BASELINE / z
    noise = cv2.GaussianBlur(rng.normal(0.0, 1.0, d.shape).astype(np.float32), (0, 0), 1.5)
    d = d + 0.12 * noise / noise.std()
    # Contention at the seam: rows where the surface changes, half their pixels from the surface across.
    seam = np.zeros(d.shape, bool)
    change = np.flatnonzero(np.any(surface[1:] != surface[:-1], axis=1))
    for r in change:
        seam[max(0, r - SEAM_PX // 2): r + SEAM_PX // 2 + 1] = True
    other = np.roll(d, SEAM_PX, axis=0)
    swap = seam & (rng.random(d.shape) < 0.5)
    d = np.where(swap, other, d)
    d = (np.rint(d / QUANTUM) * QUANTUM).astype(np.float32)
    d[~np.isfinite(z)] = np.nan
    cam = PinholeCamera(FX, FX, (WIDTH - 1) / 2, (HEIGHT - 1) / 2, WIDTH, HEIGHT)
    return Frame(np.zeros((HEIGHT, WIDTH, 3), np.uint8), d, cam, BASELINE), z, surface


def _point(z: np.ndarray, p: tuple[int, int]) -> np.ndarray:
    x, y = p
    zz = float(z[y, x])
    return np.array([(x - (WIDTH - 1) / 2) * zz / FX, (y - (HEIGHT - 1) / 2) * zz / FX, zz])


def room_cases(seeds: Sequence[int]) -> list[tuple[object, list[StressCase]]]:
    """Per seed, a wall room and a board room, two click pairs each (upper surface down to the floor)."""
    out = []
    for seed in seeds:
        rng = np.random.default_rng([seed, 1515])
        for kind in ("wall", "board"):
            room = _draw(kind, rng)
            frame, z, surface = room_frame(room, rng)
            upper = 1 if kind == "wall" else 2
            cases = []
            for _ in range(2):
                x = int(rng.integers(WIDTH // 2 - 40, WIDTH // 2 + 40))
                col = surface[:, x]
                rows_up = np.flatnonzero(col == upper)
                rows_fl = np.flatnonzero(col == 0)
                if rows_up.size < 2 * INSIDE_PX or rows_fl.size < 2 * INSIDE_PX:
                    continue
                seam = int(rows_up.max())
                y1 = int(rng.integers(max(int(rows_up.min()), seam - 200), seam - INSIDE_PX))
                y2 = int(rng.integers(seam + INSIDE_PX, min(HEIGHT - 3, seam + 200)))
                x2 = int(np.clip(x + rng.integers(-30, 31), 3, WIDTH - 4))
                if surface[y2, x2] != 0:
                    continue
                g = float(np.linalg.norm(_point(z, (x, y1)) - _point(z, (x2, y2))))
                cases.append(StressCase(kind, f"{kind}-floor", (float(x), float(y1)), (float(x2), float(y2)), g))
            out.append((frame, cases))
    return out


def run_bent_rooms(seeds: Sequence[int]) -> list[StressRecord]:
    return [measure_case(f, c, "synthetic") for f, cases in room_cases(seeds) for c in cases]
