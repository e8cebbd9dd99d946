"""Measurement segments chosen from Middlebury ground truth only: edge to edge across one straight surface.

A plane in 3D has disparity affine in (x, y), so along any image row or column its
ground-truth disparity is a straight line in the pixel position. A segment qualifies when,
along one row (or column):

1. every pixel has non-occluded ground truth and neighbouring pixels differ by less than
   ``jump_px`` (no depth discontinuity inside);
2. the GT disparity is affine over the whole run: the least-squares line leaves no residual
   above ``affine_tol_px`` (one straight surface, no crease, no curvature);
3. it is bounded at both ends by a depth discontinuity where the surface ends: beyond each
   end (skipping up to ``max_skip`` occluded/unknown pixels) the next valid pixel is farther
   away by more than ``jump_px`` of disparity. A surface that continues behind an occluder is
   not an edge-to-edge segment;
4. it is at least ``min_length_px`` long.

Of the qualifying runs, the longest are kept first and a run is skipped when it lies within
``spacing_px`` of an already kept parallel one and overlaps it, so the segments spread over
the scene. Everything is deterministic. The true 3D length comes from the GT disparity at
the two end pixels, ``Z = f B / (d + doffs)`` and Eq. 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from measure import PinholeCamera


@dataclass(frozen=True)
class GTSegment:
    """One edge-to-edge measurement with its ground truth (pixels, metres)."""

    scene: str
    p1_px: tuple[int, int]
    p2_px: tuple[int, int]
    p1_m: tuple[float, float, float]
    p2_m: tuple[float, float, float]
    length_m: float
    orientation: str  # "row" | "column"
    max_residual_px: float  # of the affine fit to the GT disparity


@dataclass(frozen=True)
class SegmentRules:
    jump_px: float = 1.0
    affine_tol_px: float = 0.25
    min_length_px: int = 60
    max_skip: int = 30
    spacing_px: int = 12
    max_segments: int = 12
    far_ends: bool = True  # rule 3; False keeps runs whatever lies beyond their ends (stress protocol)


def _runs(d: np.ndarray, ok: np.ndarray, jump: float) -> list[tuple[int, int]]:
    """Maximal [start, end] index runs of ``ok`` pixels with |d[i+1] - d[i]| < jump."""
    inner = ok[:-1] & ok[1:] & (np.abs(np.diff(np.where(ok, d, 0.0))) < jump)
    starts = np.flatnonzero(ok & ~np.r_[False, inner])
    ends = np.flatnonzero(ok & ~np.r_[inner, False])
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def _ends_behind(d: np.ndarray, ok: np.ndarray, s: int, e: int, rules: SegmentRules) -> bool:
    """Beyond each end the next valid pixel (within max_skip) is farther away by > jump_px."""
    for end, step in ((s, -1), (e, 1)):
        i = end + step
        found = False
        for _ in range(rules.max_skip + 1):
            if i < 0 or i >= len(d):
                return False
            if ok[i]:
                found = d[i] < d[end] - rules.jump_px
                break
            i += step
        if not found:
            return False
    return True


def _line_candidates(gt: np.ndarray, valid: np.ndarray, rules: SegmentRules, orientation: str):
    arr, ok = (gt, valid) if orientation == "row" else (gt.T, valid.T)
    found = []
    for line in range(arr.shape[0]):
        d, m = arr[line].astype(np.float64), ok[line]
        for s, e in _runs(d, m, rules.jump_px):
            if e - s + 1 < rules.min_length_px or (rules.far_ends and not _ends_behind(d, m, s, e, rules)):
                continue
            x = np.arange(s, e + 1, dtype=np.float64)
            coef = np.polyfit(x, d[s : e + 1], 1)
            resid = float(np.abs(np.polyval(coef, x) - d[s : e + 1]).max())
            if resid <= rules.affine_tol_px:
                found.append((e - s + 1, line, s, e, resid))
    return found


def find_segments(
    name: str,
    gt_disparity: np.ndarray,
    nonocc_mask: np.ndarray,
    camera: PinholeCamera,
    baseline_m: float,
    doffs: float,
    rules: SegmentRules = SegmentRules(),
) -> list[GTSegment]:
    """Edge-to-edge segments across one straight surface, from ground truth alone (module docstring)."""
    valid = nonocc_mask & np.isfinite(gt_disparity)
    chosen: list[GTSegment] = []
    for orientation in ("row", "column"):
        cands = sorted(_line_candidates(gt_disparity, valid, rules, orientation), key=lambda c: (-c[0], c[1], c[2]))
        kept: list[tuple[int, int, int]] = []
        for length, line, s, e, resid in cands:
            if any(abs(line - kl) < rules.spacing_px and s <= ke and ks <= e for kl, ks, ke in kept):
                continue
            kept.append((line, s, e))
            p1 = (s, line) if orientation == "row" else (line, s)
            p2 = (e, line) if orientation == "row" else (line, e)
            pts = [_backproject(camera, baseline_m, doffs, p, float(gt_disparity[p[1], p[0]])) for p in (p1, p2)]
            chosen.append(
                GTSegment(
                    scene=name,
                    p1_px=p1,
                    p2_px=p2,
                    p1_m=pts[0],
                    p2_m=pts[1],
                    length_m=float(np.linalg.norm(np.subtract(pts[1], pts[0]))),
                    orientation=orientation,
                    max_residual_px=resid,
                )
            )
            if len(kept) >= rules.max_segments // 2:
                break
    return chosen


def scene_segments(scene, rules: SegmentRules = SegmentRules()) -> list[GTSegment]:
    """:func:`find_segments` for a ``device.sources.middlebury.MiddleburyScene``."""
    return find_segments(scene.name, scene.gt_disparity, scene.nonocc_mask, scene.camera, scene.baseline_m, scene.doffs, rules)


def _backproject(cam: PinholeCamera, baseline_m: float, doffs: float, p: tuple[int, int], d: float) -> tuple[float, float, float]:
    z = cam.fx * baseline_m / (d + doffs)
    return ((p[0] - cam.cx) * z / cam.fx, (p[1] - cam.cy) * z / cam.fy, z)
