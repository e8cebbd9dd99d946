"""Middlebury stress protocol (`depthruler eval middlebury --protocol stress`): clicks as people make them.

For each ground-truth segment of ``evaluation.gt_segments`` (one straight surface, edge to edge):

- ``exact``: the segment's end pixels; truth its length.
- ``jitter``: three click pairs with 3-px Gaussian jitter per coordinate; truth the segment's length.
- ``inside``: three pairs with both ends moved 5-20 px inside the surface; truth from the ground truth
  at the clicked pixels.
- ``piece``: three 15-40 px pieces inside the segment; truth from the ground truth at the clicked pixels.
- ``long``: segments of at least ``LONG_PX`` px (same rules), exact ends.
- ``nogap``: segments found without the "far side is farther at both ends" rule, keeping only those
  that break it (a nearer surface, or nothing, beyond an end) but not at both ends: no-gap geometry
  the gap rule must not fire on; truth from the ground truth at the end pixels.
- ``recess``: the same kind of segment with a nearer surface beyond *both* ends in the ground truth
  (the median of the valid ground truth over the 25 px beyond each end, the extension the gap rule
  looks at, nearer by more than the segments' 1-px jump): the geometry
  of a gap (the space between two boxes) whose truth here is the recessed surface itself. Clicks
  at the edges of such a surface are ambiguous; the gap rule answering across the gap is reported
  as its own rate, not as a false positive.

Disparities: ``sgbm`` (device/sources/sgbm.py, as in the edge protocol), ``bm`` (OpenCV StereoBM, block 15,
left band filled the same way), ``gt_out50`` (the ground truth with 50 % of all pixels replaced by a
value drawn uniformly from the scene's disparity range).

Scenes split into a dev half (used to calibrate the uncertainty and the verdict, measure/verdict.py)
and a held-out half (``DEV_SCENES`` / ``HELD_OUT_SCENES``); the report gives both.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from evaluation.stress import StressCase, StressRecord, measure_case

DISPARITIES: tuple[str, ...] = ("sgbm", "bm", "gt_out50")
DEV_SCENES: tuple[str, ...] = ("Adirondack", "Piano", "Playroom", "Shelves")
HELD_OUT_SCENES: tuple[str, ...] = ("Motorcycle", "Pipes", "Recycle", "Teddy")
LONG_PX = 100
EXTENSION_PX = 25  # the gap rule's extension (MeasureOptions.extension_px)
JITTER_PX = 3.0


def bm_disparity(left_bgr: np.ndarray, right_bgr: np.ndarray, num_disparities: int, block: int = 15) -> np.ndarray:
    """OpenCV StereoBM disparity (px, float32, NaN = no match), its blind left band filled by padding."""
    import cv2

    gl = cv2.cvtColor(left_bgr, cv2.COLOR_BGR2GRAY)
    gr = cv2.cvtColor(right_bgr, cv2.COLOR_BGR2GRAY)
    pad = num_disparities
    gl = cv2.copyMakeBorder(gl, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    gr = cv2.copyMakeBorder(gr, 0, 0, pad, 0, cv2.BORDER_REPLICATE)
    bm = cv2.StereoBM.create(numDisparities=num_disparities, blockSize=block)
    raw = bm.compute(gl, gr)[:, pad:]
    d = raw.astype(np.float32) / 16.0
    d[raw <= 0] = np.nan
    d[d > np.arange(d.shape[1], dtype=np.float32)[None, :]] = np.nan
    return d


def outlier_disparity(gt: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Ground truth with ``fraction`` of all known pixels replaced by uniform values over its range."""
    lo, hi = float(np.nanmin(gt)), float(np.nanmax(gt))
    out = gt.astype(np.float32).copy()
    pick = np.isfinite(gt) & (rng.random(gt.shape) < fraction)
    out[pick] = rng.uniform(lo, hi, int(pick.sum())).astype(np.float32)
    return out


def _gt_point(scene: Any, p: tuple[float, float]) -> np.ndarray | None:
    x, y = int(round(p[0])), int(round(p[1]))
    d = float(scene.gt_disparity[y, x])
    if not (math.isfinite(d) and scene.nonocc_mask[y, x]):
        return None
    cam = scene.camera
    z = cam.fx * scene.baseline_m / (d + scene.doffs)
    return np.array([(x - cam.cx) * z / cam.fx, (y - cam.cy) * z / cam.fy, z])


def _gt_truth(scene: Any, p1: tuple[float, float], p2: tuple[float, float]) -> float | None:
    a, b = _gt_point(scene, p1), _gt_point(scene, p2)
    return None if a is None or b is None else float(np.linalg.norm(a - b))


def stress_cases(scene: Any, rng: np.random.Generator, max_segments: int | None = None) -> list[StressCase]:
    """The click pairs of the module docstring for one ``device.sources.middlebury.MiddleburyScene``."""
    from evaluation.gt_segments import SegmentRules, scene_segments

    w, h = scene.camera.width, scene.camera.height
    hi = np.array([w - 1, h - 1, w - 1, h - 1], float)
    cases: list[StressCase] = []

    def add(cond: str, p1, p2, truth: float | None) -> None:
        p1 = (float(p1[0]), float(p1[1]))
        p2 = (float(p2[0]), float(p2[1]))
        if truth is not None and truth > 0 and p1 != p2:
            cases.append(StressCase(scene.name, cond, p1, p2, truth))

    segs = scene_segments(scene)[:max_segments] if max_segments else scene_segments(scene)
    for s in segs:
        a, b = np.array(s.p1_px, float), np.array(s.p2_px, float)
        n = int(round(np.abs(b - a).max()))
        u = (b - a) / n  # one pixel step along the major axis
        add("exact", a, b, s.length_m)
        for _ in range(3):
            q = np.clip(np.rint(np.r_[a, b] + rng.normal(0.0, JITTER_PX, 4)), 0, hi)
            add("jitter", q[:2], q[2:], s.length_m)
        for _ in range(3):
            k1, k2 = rng.integers(5, 21, 2)
            if n - k1 - k2 >= 10:
                p1, p2 = a + k1 * u, b - k2 * u
                add("inside", p1, p2, _gt_truth(scene, p1, p2))
        for _ in range(3):
            k = int(rng.integers(15, 41))
            if n > k + 2:
                s0 = int(rng.integers(1, n - k))
                p1, p2 = a + s0 * u, a + (s0 + k) * u
                add("piece", p1, p2, _gt_truth(scene, p1, p2))
    rules = SegmentRules()
    for s in scene_segments(scene, replace(rules, min_length_px=LONG_PX)):
        add("long", s.p1_px, s.p2_px, s.length_m)
    ruled = {(s.p1_px, s.p2_px) for s in scene_segments(scene, replace(rules, max_segments=48))}
    loose = scene_segments(scene, replace(rules, far_ends=False, max_segments=24))
    for s in [s for s in loose if (s.p1_px, s.p2_px) not in ruled][: (max_segments or 12)]:
        add("recess" if nearer_beyond_both_ends(scene, s.p1_px, s.p2_px, rules) else "nogap", s.p1_px, s.p2_px, s.length_m)
    return cases


def nearer_beyond_both_ends(scene: Any, p1: tuple[int, int], p2: tuple[int, int], rules: Any, length: int = EXTENSION_PX) -> bool:
    """Beyond each end of the row or column segment p1-p2, the median of the valid ground truth over
    the ``length`` px the gap rule looks at (its extension) is nearer than the end by more than
    ``rules.jump_px``: a nearer surface dominates both extensions."""
    gt, ok = scene.gt_disparity, scene.nonocc_mask & np.isfinite(scene.gt_disparity)
    h, w = gt.shape
    step = np.sign(np.subtract(p2, p1)).astype(int)
    k = np.arange(1, length + 1)
    for (x, y), (sx, sy) in ((p1, -step), (p2, step)):
        xs, ys = x + sx * k, y + sy * k
        inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
        xs, ys = xs[inside], ys[inside]
        v = gt[ys, xs][ok[ys, xs]]
        if v.size == 0 or not float(np.median(v)) > float(gt[y, x]) + rules.jump_px:
            return False
    return True


def scene_frames(scene: Any, rng: np.random.Generator, disparities: Sequence[str] = DISPARITIES) -> dict[str, Any]:
    """One measure.Frame per disparity source of the module docstring."""
    from device.sources.middlebury import scene_frame, scene_sgbm_config
    from device.sources.sgbm import compute_disparity

    config = scene_sgbm_config(scene)
    out = {}
    for name in disparities:
        conf = None
        if name == "sgbm":
            d, conf = compute_disparity(scene.left, scene.right, config)
        elif name == "bm":
            d = bm_disparity(scene.left, scene.right, config.num_disparities)
        elif name == "gt_out50":
            d = outlier_disparity(scene.gt_disparity, 0.5, rng)
        else:
            raise ValueError(f"disparity {name!r} is unknown; use one of {', '.join(DISPARITIES)}")
        out[name] = scene_frame(scene, d, conf)
    return out


def run_stress_middlebury(
    data_dir: Path,
    scenes: Sequence[str] | None = None,
    *,
    disparities: Sequence[str] = DISPARITIES,
    max_segments: int | None = None,
    seed: int = 0,
    on_progress=None,
) -> list[StressRecord]:
    """Every stress case of every selected scene under every disparity source."""
    from device.sources.middlebury import load_scene

    from evaluation.middlebury import scene_dirs

    records: list[StressRecord] = []
    for path in scene_dirs(data_dir, scenes):
        scene = load_scene(path)
        rng = np.random.default_rng([seed, sum(map(ord, scene.name))])
        cases = stress_cases(scene, rng, max_segments)
        for name, frame in scene_frames(scene, rng, disparities).items():
            records += [measure_case(frame, c, name) for c in cases]
        if on_progress:
            on_progress(scene.name)
    return records


TITLE = "Middlebury stress protocol"


def write_stress_middlebury(out_dir: Path, records: Sequence[StressRecord], setup: dict[str, Any]) -> dict[str, Path]:
    from evaluation.stress import write_stress_report

    splits = {
        "dev": [r for r in records if r.case.group in DEV_SCENES],
        "held-out": [r for r in records if r.case.group not in DEV_SCENES],
    }
    return write_stress_report(out_dir, TITLE, setup, splits, notes(sorted({r.case.group for r in records})), scenes=True)


def notes(names: Sequence[str]) -> list[str]:
    """The report's opening paragraphs for the scenes ``names``."""
    return [
        "Clicks as people make them on real stereo (evaluation/stress_middlebury.py). "
        f"Scenes: {', '.join(names)}; dev = {', '.join(DEV_SCENES)} (the uncertainty scale and the "
        "verdict thresholds of measure/verdict.py were set on these), held-out = the rest.",
        "",
        "Conditions: exact end pixels; 3-px click jitter; ends 5-20 px inside; 15-40 px pieces; long "
        f"segments (>= {LONG_PX} px); nogap = segments without the far-side rule; recess = such segments "
        "with a nearer surface beyond both ends (gap geometry, truth the recessed surface). Disparities: sgbm, bm "
        "(StereoBM), gt_out50 (ground truth, 50 % of pixels uniform outliers). A = Eq. 8 of the robust "
        "(default) answer; coverage = share of answered cases whose error is within 1σ / 2σ; good & A<90 "
        "and good are shares of all cases; robust≪basic = robust A < 90 while basic A >= 90.",
    ]


def stress_middlebury_markdown(data: dict[str, Any]) -> str:
    """report.md from its results.json ``data``."""
    from evaluation.stress import stress_markdown

    names = sorted({r["group"] for d in data["splits"].values() for r in d["records"]})
    return stress_markdown(TITLE, notes(names), data)
