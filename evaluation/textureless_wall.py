"""The textureless-wall study (`depthruler eval wall`): segments on a plain painted wall beside a printed
poster, rendered as a stereo pair and matched by the project's SGBM (``sim:plain-wall?mode=stereo``).

Per (distance, seed): ``WALL_SEGMENTS`` random segments lying wholly on the plain wall (40-400 px, any
direction, at least ``MARGIN_PX`` from the poster and the image border) and ``POSTER_SEGMENTS`` on the
poster (the textured control); truth from the renderer's depth at the clicked pixels. Each is measured
by ``robust`` on the frame as the source delivers it and on the same frame without its confidence map
(``confidence=None``: what the method did before it read the matcher's confidence).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from evaluation.stress import StressCase, StressRecord, measure_case

DISTANCES_M: tuple[float, ...] = (1.5, 2.5, 4.0)
DEV_SEEDS: tuple[int, ...] = (0, 1)
HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001)
WALL_SEGMENTS = 12
POSTER_SEGMENTS = 4
MARGIN_PX = 12


def _point(truth: Any, camera: Any, p: tuple[int, int]) -> np.ndarray:
    z = float(truth.depth_m[p[1], p[0]])
    return np.array([(p[0] - camera.cx) * z / camera.fx, (p[1] - camera.cy) * z / camera.fy, z])


def _segments(mask: np.ndarray, count: int, rng: np.random.Generator) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``count`` segments whose every pixel lies in ``mask`` (tries a bounded number of draws)."""
    import cv2

    inner = cv2.erode(mask.astype(np.uint8), np.ones((2 * MARGIN_PX + 1, 2 * MARGIN_PX + 1), np.uint8)) > 0
    ys, xs = np.nonzero(inner)
    out: list[tuple[tuple[int, int], tuple[int, int]]] = []
    for _ in range(50 * count):
        if len(out) == count or xs.size == 0:
            break
        i = int(rng.integers(xs.size))
        length, angle = rng.uniform(40, 400), rng.uniform(0, np.pi)
        a = (int(xs[i]), int(ys[i]))
        b = (int(round(a[0] + length * np.cos(angle))), int(round(a[1] + length * np.sin(angle))))
        h, w = mask.shape
        if not (0 <= b[0] < w and 0 <= b[1] < h):
            continue
        k = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]))) + 1
        xs_, ys_ = np.rint(np.linspace(a[0], b[0], k)).astype(int), np.rint(np.linspace(a[1], b[1], k)).astype(int)
        if inner[ys_, xs_].all():
            out.append((a, b))
    return out


def wall_cases(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[tuple[Any, list[StressCase]]]:
    """(stereo frame, cases) for every (seed, distance)."""
    from sim.scenario import make_model
    from sim.scenes import SceneParams, get_view
    from sim.stereo import stereo_frame

    out = []
    for seed in seeds:
        rng = np.random.default_rng([seed, 4242])
        for dist in distances:
            params = SceneParams(scene="plain-wall", distance_m=float(dist))
            frame, truth = stereo_frame(params, make_model("indoor"), np.random.default_rng([seed, int(dist * 100)]))
            view = get_view(params)
            cases = []
            for name, count in (("wall", WALL_SEGMENTS), ("poster", POSTER_SEGMENTS)):
                for a, b in _segments(view.obj == view.objects.index(name), count, rng):
                    g = float(np.linalg.norm(_point(truth, frame.camera, a) - _point(truth, frame.camera, b)))
                    cases.append(StressCase(name, f"{name}-{dist:g}m", (float(a[0]), float(a[1])), (float(b[0]), float(b[1])), g))
            out.append((frame, cases))
    return out


def run_textureless_wall(seeds: Sequence[int], distances: Sequence[float] = DISTANCES_M) -> list[StressRecord]:
    """Every case measured with the frame's confidence ("sgbm") and without it ("sgbm-no-confidence")."""
    records: list[StressRecord] = []
    for frame, cases in wall_cases(seeds, distances):
        bare = replace(frame, confidence=None)
        records += [measure_case(frame, c, "sgbm") for c in cases]
        records += [measure_case(bare, c, "sgbm-no-confidence") for c in cases]
    return records
