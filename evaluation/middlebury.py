"""Accuracy on real stereo: the Middlebury 2014 scenes ($DEPTHRULER_SHARED/data/middlebury).

For each scene two disparity conditions are measured with the same segments:

- ``sgbm``: OpenCV SGBM on the rectified pair (device/sources/sgbm.py, the scene's ``ndisp`` rounded up to
  a multiple of 16, every other parameter the SGBMConfig default; written into the report).
- ``gt_contended``: the paper's sensor conditions on real geometry: the ground truth rounded to whole
  pixels, and in contended regions half of the pixels replaced by a wrong match
  (:func:`contended_disparity`).

Segments run edge to edge across one straight surface and come from evaluation/gt_segments.py, which
selects them on the ground truth; their true length is the distance between the ground-truth 3D
points of their end pixels.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evaluation import report
from measure import accuracy, signed_error_pct
from evaluation.sim_study import MethodOutcome, measure_all, warm_up
from evaluation.report import METHODS, EvalError


CONDITIONS: tuple[str, ...] = ("sgbm", "gt_contended")
CONDITION_LABELS = {
    "sgbm": "SGBM disparity",
    "gt_contended": "ground truth, integer + 50 % contention outliers",
}


@dataclass(frozen=True)
class ContentionModel:
    """Outlier model of a three-camera sensor applied to ground-truth disparity (pixels).

    Contended regions are (a) a band of ``edge_band_px`` pixels around depth edges, i.e. where
    neighbouring ground-truth disparities differ by more than ``edge_jump_px`` or the ground truth
    is unknown next to known, and (b) low texture, where the grey level's standard deviation over a
    ``texture_window`` square is below ``texture_std``. There each pixel independently, with
    probability ``fraction``, carries the other pair's wrong match: an integer disparity drawn
    uniformly from the scene's ground-truth disparity range (a match to some other surface of the
    scene). Everywhere else the disparity is the ground truth rounded to ``quantization_px``.
    """

    fraction: float = 0.5
    quantization_px: float = 1.0
    edge_jump_px: float = 1.5
    edge_band_px: int = 3
    texture_window: int = 7
    texture_std: float = 1.5
    seed: int = 0

    def __post_init__(self) -> None:
        if not (0.0 <= self.fraction <= 1.0):
            raise ValueError(f"fraction={self.fraction} must lie in [0, 1]")
        if self.quantization_px <= 0:
            raise ValueError(f"quantization_px={self.quantization_px} must be positive")
        if self.edge_band_px < 0 or self.texture_window < 1 or self.texture_window % 2 == 0:
            raise ValueError("edge_band_px must be >= 0 and texture_window a positive odd number")


def contended_regions(gt_disparity: np.ndarray, image_bgr: np.ndarray, model: ContentionModel) -> np.ndarray:
    """Bool mask of the contended pixels (depth-edge band or low texture) of a scene."""
    import cv2

    gt = gt_disparity.astype(np.float32)
    known = np.isfinite(gt)
    filled = np.where(known, gt, 0.0).astype(np.float32)
    edge = np.zeros(gt.shape, bool)
    for dy, dx in ((0, 1), (1, 0)):
        a, b = filled[: gt.shape[0] - dy, : gt.shape[1] - dx], filled[dy:, dx:]
        ka, kb = known[: gt.shape[0] - dy, : gt.shape[1] - dx], known[dy:, dx:]
        jump = (ka & kb & (np.abs(a - b) > model.edge_jump_px)) | (ka != kb)
        edge[: gt.shape[0] - dy, : gt.shape[1] - dx] |= jump
        edge[dy:, dx:] |= jump
    if model.edge_band_px > 0:
        k = 2 * model.edge_band_px + 1
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)
    w = (model.texture_window, model.texture_window)
    mean = cv2.blur(grey, w)
    var = np.maximum(cv2.blur(grey * grey, w) - mean * mean, 0.0)
    low_texture = np.sqrt(var) < model.texture_std
    return edge | low_texture


def contended_disparity(gt_disparity: np.ndarray, image_bgr: np.ndarray, model: ContentionModel) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth (px, NaN unknown) degraded by :class:`ContentionModel`: (disparity float32, outlier mask)."""
    rng = np.random.default_rng(model.seed)
    gt = gt_disparity.astype(np.float64)
    known = np.isfinite(gt)
    q = model.quantization_px
    disp = np.where(known, np.round(gt / q) * q, np.nan)
    contended = contended_regions(gt_disparity, image_bgr, model) & known
    outlier = contended & (rng.random(gt.shape) < model.fraction)
    lo, hi = np.nanmin(gt), np.nanmax(gt)
    wrong = rng.integers(int(math.floor(lo)), int(math.ceil(hi)) + 1, size=gt.shape).astype(np.float64)
    disp[outlier] = wrong[outlier]
    return disp.astype(np.float32), outlier


@dataclass(frozen=True)
class SegmentResult:
    """One click pair on one scene under one disparity condition, measured by every method."""

    scene: str
    condition: str
    p1_px: tuple[float, float]
    p2_px: tuple[float, float]
    truth_m: float
    outcomes: tuple[MethodOutcome, ...]

    def outcome(self, method: str) -> MethodOutcome:
        return next(o for o in self.outcomes if o.method == method)


def scene_dirs(data_dir: Path, names: Sequence[str] | None = None) -> list[Path]:
    """The scene folders under ``data_dir`` (those with im0.png), optionally only ``names``."""
    if not data_dir.is_dir():
        raise EvalError(f"{data_dir} does not exist; pass --data pointing at the Middlebury folder ($DEPTHRULER_SHARED/data/middlebury)")
    dirs = sorted(p for p in data_dir.iterdir() if (p / "im0.png").is_file() and (p / "disp0GT.pfm").is_file())
    if names:
        wanted = set(names)
        missing = wanted - {p.name for p in dirs}
        if missing:
            raise EvalError(f"scene(s) {', '.join(sorted(missing))} not found in {data_dir}; have {', '.join(p.name for p in dirs)}")
        dirs = [p for p in dirs if p.name in wanted]
    if not dirs:
        raise EvalError(f"{data_dir} holds no Middlebury scene (folders with im0.png and disp0GT.pfm)")
    return dirs


@dataclass(frozen=True)
class ClickJitter:
    """How a person's clicks scatter around a segment's end pixels: besides the exact end pixels,
    ``extra`` click pairs per segment with Gaussian jitter of ``sigma_px`` on each coordinate,
    rounded to whole pixels (a tap lands on a pixel) and kept inside the image."""

    extra: int = 2
    sigma_px: float = 1.5
    seed: int = 0

    def __post_init__(self) -> None:
        if self.extra < 0 or self.sigma_px < 0:
            raise ValueError(f"extra={self.extra} and sigma_px={self.sigma_px} must be >= 0")


def clicks_for(
    p1: tuple[float, float], p2: tuple[float, float], jitter: ClickJitter, rng: np.random.Generator, width: int, height: int
) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The exact end pixels, then ``jitter.extra`` jittered click pairs (pixels)."""
    out = [(p1, p2)]
    hi = np.array([width - 1, height - 1, width - 1, height - 1], float)
    for _ in range(jitter.extra):
        q = np.clip(np.rint(np.array([*p1, *p2]) + rng.normal(0.0, jitter.sigma_px, 4)), 0, hi)
        if (q[0], q[1]) != (q[2], q[3]):
            out.append(((float(q[0]), float(q[1])), (float(q[2]), float(q[3]))))
    return out


def _segments(scene: Any, max_segments: int | None) -> list[tuple[tuple[float, float], tuple[float, float], float]]:
    """(p1_px, p2_px, true length m) of the scene's evaluation segments, from evaluation/gt_segments.py."""
    from evaluation.gt_segments import scene_segments

    segs = scene_segments(scene)
    return [
        ((float(s.p1_px[0]), float(s.p1_px[1])), (float(s.p2_px[0]), float(s.p2_px[1])), float(s.length_m))
        for s in (segs[:max_segments] if max_segments else segs)
    ]


@dataclass(frozen=True)
class ScenePlan:
    """One scene's work for a worker: its folder, the click pairs (drawn in the caller, in scene
    order, so any executor gives the serial run's clicks) and the contention model."""

    path: Path
    clicks: tuple[tuple[tuple[float, float], tuple[float, float], float], ...]  # (c1, c2, true length m)
    n_segments: int
    model: ContentionModel


def run_scene(plan: ScenePlan) -> tuple[str, dict[str, Any], list[SegmentResult]]:
    """SGBM and the contended ground truth of one scene, and every click pair measured on both."""
    from device.sources.middlebury import load_scene, scene_frame, scene_sgbm_config
    from device.sources.sgbm import compute_disparity

    scene = load_scene(plan.path)
    config = scene_sgbm_config(scene)
    t0 = time.perf_counter()
    disp, conf = compute_disparity(scene.left, scene.right, config)
    sgbm_s = time.perf_counter() - t0
    degraded, outliers = contended_disparity(scene.gt_disparity, scene.left, plan.model)
    frames = {"sgbm": scene_frame(scene, disp, conf), "gt_contended": scene_frame(scene, degraded)}
    gt = scene.gt_disparity
    both = np.isfinite(disp) & np.isfinite(gt)
    setup = {
        "size": [int(scene.camera.width), int(scene.camera.height)],
        "sgbm_config": asdict(config),
        "sgbm_seconds": sgbm_s,
        "sgbm_valid_fraction": float(np.isfinite(disp).mean()),
        "sgbm_within_1px": float(np.mean(np.abs(disp[both] - gt[both]) <= 1.0)) if both.any() else None,
        "outlier_fraction": float(outliers.mean()),
        "n_segments": plan.n_segments,
    }
    results = []
    for c1, c2, truth in plan.clicks:
        for cond in CONDITIONS:
            warm_up(frames[cond], c1, c2)
            results.append(SegmentResult(scene.name, cond, c1, c2, truth, measure_all(frames[cond], c1, c2)))
    return scene.name, setup, results


def run_middlebury(
    data_dir: Path,
    *,
    scenes: Sequence[str] | None = None,
    max_segments: int | None = None,
    model: ContentionModel = ContentionModel(),
    clicks: ClickJitter = ClickJitter(),
    on_progress: Callable[[str], None] | None = None,
    executor: Any = None,
) -> tuple[dict[str, Any], list[SegmentResult]]:
    """Measure every selected segment of every scene under both conditions; (setup, results).

    Scenes run on ``executor`` (batch/executors.py; default: in this process), one scene per
    worker call; the results are the serial run's whatever the executor."""
    from batch.executors import InProcessExecutor
    from evaluation.gt_segments import SegmentRules
    from device.sources.middlebury import load_scene

    rng = np.random.default_rng(clicks.seed)
    setup: dict[str, Any] = {
        "data": str(data_dir),
        "scenes": {},
        "contention_model": asdict(model),
        "segment_rules": asdict(SegmentRules()),
        "clicks": asdict(clicks),
    }
    plans = []
    for path in scene_dirs(data_dir, scenes):
        scene = load_scene(path)
        segs = _segments(scene, max_segments)
        pairs = tuple(
            (c1, c2, truth)
            for p1, p2, truth in segs
            for c1, c2 in clicks_for(p1, p2, clicks, rng, scene.camera.width, scene.camera.height)
        )
        plans.append(ScenePlan(path, pairs, len(segs), model))
    done: dict[int, tuple[str, dict[str, Any], list[SegmentResult]]] = {}
    for i, (name, scene_setup, scene_results) in (executor or InProcessExecutor()).imap(run_scene, plans):
        done[i] = (name, scene_setup, scene_results)
        if on_progress:
            on_progress(name)
    results: list[SegmentResult] = []
    for i in range(len(plans)):
        name, scene_setup, scene_results = done[i]
        setup["scenes"][name] = scene_setup
        results.extend(scene_results)
    return setup, results


def summarize_middlebury(setup: dict[str, Any], results: Sequence[SegmentResult]) -> dict[str, Any]:
    """Per scene and overall accuracy (mean, median, std) per method and condition.

    As in the simulated study, statistics use the segments where every method answered; each
    method's failures are counted under ``failed``.
    """
    names = list(setup["scenes"])
    out: dict[str, Any] = {"setup": setup, "conditions": {}}
    for cond in CONDITIONS:
        rows = [r for r in results if r.condition == cond]
        truth = np.array([r.truth_m for r in rows])
        scene = np.array([r.scene for r in rows])
        measured = {m: np.array([r.outcome(m).distance_m for r in rows]) for m in METHODS}
        common = np.logical_and.reduce([np.isfinite(measured[m]) for m in METHODS]) if rows else np.zeros(0, bool)
        methods = {}
        for m in METHODS:
            acc = accuracy(truth, measured[m])[common]
            methods[m] = {
                "overall": report.summary(acc),
                "by_scene": report.grouped(scene[common], acc, names),
                "failed": int(np.sum(~np.isfinite(measured[m]))),
                "gap_detected": int(sum(r.outcome(m).gap_detected for r in rows)),
                "timing_ms": report.timing_summary(np.array([r.outcome(m).elapsed_ms for r in rows])),
            }
        out["conditions"][cond] = {"methods": methods, "n_measurements": len(rows), "n_common": int(common.sum())}
    out["methods"] = out["conditions"]["sgbm"]["methods"]
    return out


def plot_names() -> dict[str, str]:
    """The plots of a report, by the name report.md refers to them with."""
    return {"segments": "segments.png", **{f"bars_{c}": f"accuracy_by_scene_{c}.png" for c in CONDITIONS},
            **{f"hist_{c}": f"error_histogram_{c}.png" for c in CONDITIONS}}


def write_middlebury_report(out_dir: Path, summary: dict[str, Any], results: Sequence[SegmentResult]) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    names = list(summary["setup"]["scenes"])
    paths: dict[str, Path] = {}
    for cond in CONDITIONS:
        ms = summary["conditions"][cond]["methods"]
        paths[f"bars_{cond}"] = report.plot_grouped_bars(
            out_dir / plot_names()[f"bars_{cond}"],
            names + ["all"],
            {m: {**ms[m]["by_scene"], "all": ms[m]["overall"]} for m in METHODS},
            title=f"Middlebury, {CONDITION_LABELS[cond]}: median accuracy per scene",
            xlabel="scene  (segments)",
            value="median",
            spread=None,
        )
        rows = [r for r in results if r.condition == cond]
        truth = np.array([r.truth_m for r in rows])
        paths[f"hist_{cond}"] = report.plot_error_histograms(
            out_dir / plot_names()[f"hist_{cond}"],
            {m: signed_error_pct(truth, np.array([r.outcome(m).distance_m for r in rows])) for m in METHODS},
            title=f"Middlebury, {CONDITION_LABELS[cond]}: signed relative error",
        )
    paths["segments"] = plot_segments(out_dir / plot_names()["segments"], Path(summary["setup"]["data"]), names, results)
    report.write_json(out_dir / "results.json", {**summary, "segments": [_segment_json(r) for r in results]})
    (out_dir / "report.md").write_text(middlebury_markdown(summary, {k: p.name for k, p in paths.items()}))
    return paths


def plot_segments(path: Path, data_dir: Path, names: Sequence[str], results: Sequence[SegmentResult]) -> Path:
    """Each scene's left image with its measured click pairs (SGBM condition), green where the
    robust method is within 5 % of the truth, red elsewhere."""
    import cv2

    plt = report.pyplot()
    cols = 4
    rows = max(1, math.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.8 * cols, 2.1 * rows), dpi=80)
    axes = np.atleast_1d(axes).ravel()
    for ax, name in zip(axes, names):
        img = cv2.imread(str(data_dir / name / "im0.png"), cv2.IMREAD_COLOR)
        if img is not None:
            # A half-size thumbnail keeps the PNG small; extent keeps the axes in full-size pixels.
            h, w = img.shape[:2]
            thumb = cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
            ax.imshow(cv2.cvtColor(thumb, cv2.COLOR_BGR2RGB), extent=(-0.5, w - 0.5, h - 0.5, -0.5))
        for r in results:
            if r.scene != name or r.condition != "sgbm":
                continue
            a = accuracy(r.truth_m, r.outcome("robust").distance_m)
            ok = bool(np.isfinite(a) and a >= 95.0)
            ax.plot([r.p1_px[0], r.p2_px[0]], [r.p1_px[1], r.p2_px[1]], "-", color="#2ca02c" if ok else "#d62728", lw=1.6)
        ax.set_title(name, fontsize=9)
    for ax in axes:
        ax.axis("off")
    return report.save(fig, path, "Middlebury segments (all click pairs); green: robust within 5 % on SGBM, red: not")


def _segment_json(r: SegmentResult) -> dict[str, Any]:
    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        "scene": r.scene,
        "condition": r.condition,
        "p1_px": list(r.p1_px),
        "p2_px": list(r.p2_px),
        "truth_m": r.truth_m,
        "measured_m": {o.method: num(o.distance_m) for o in r.outcomes},
        "gap_detected": {o.method: o.gap_detected for o in r.outcomes},
        "fit": {o.method: o.fit for o in r.outcomes},
        "errors": {o.method: o.error for o in r.outcomes if o.error},
    }


def middlebury_markdown(summary: dict[str, Any], plots: dict[str, str]) -> str:
    f = report.fmt
    setup = summary["setup"]
    names = list(setup["scenes"])
    model = setup["contention_model"]
    rules = setup["segment_rules"]
    clicks = setup["clicks"]
    any_cfg = next(iter(setup["scenes"].values()))["sgbm_config"] if names else {}
    lines = [
        "# Accuracy on real stereo (Middlebury 2014, quarter resolution)",
        "",
        "Scenes: D. Scharstein, H. Hirschmüller, Y. Kitajima, G. Krathwohl, N. Nesic, X. Wang and "
        "P. Westling, High-resolution stereo datasets with subpixel-accurate ground truth, GCPR 2014 "
        "(Teddy: D. Scharstein and R. Szeliski, CVPR 2003).",
        "",
        "## Setup",
        "",
        "- **Segments** come from `evaluation/gt_segments.py`, chosen on the ground truth alone: image rows "
        "or columns whose non-occluded ground-truth disparity is affine along the run (one straight "
        f"surface: residual ≤ {rules['affine_tol_px']:g} px, neighbours differ by < {rules['jump_px']:g} px) "
        "and that end at a depth edge on both sides (the next valid pixel beyond each end is farther "
        f"by > {rules['jump_px']:g} px of disparity, skipping up to {rules['max_skip']} occluded pixels), "
        f"at least {rules['min_length_px']} px long; the longest first, spread at least "
        f"{rules['spacing_px']} px apart, at most {rules['max_segments']} per scene (half rows, half "
        "columns). The end pixels are the surface's last pixels before its edges, where a person "
        "would click. The true length is the distance between their ground-truth 3D points "
        "(`disp0GT.pfm`, calib.txt, Eq. 2).",
        "- **SGBM** (`device/sources/sgbm.py`, OpenCV `StereoSGBM`): "
        + ", ".join(f"{k}={v}" for k, v in any_cfg.items() if k != "num_disparities")
        + "; num_disparities = the scene's `ndisp` rounded up to a multiple of 16 (per scene below). "
        "P1/P2 None means 8·3·bs² and 32·3·bs².",
        f"- **Ground truth + contention**: the ground truth rounded to {model['quantization_px']:g} px; "
        f"contended pixels are those within {model['edge_band_px']} px of a depth edge (neighbouring "
        f"ground-truth disparities differ by > {model['edge_jump_px']:g} px, or known next to unknown) "
        f"or in low texture (grey-level std < {model['texture_std']:g} over {model['texture_window']}x"
        f"{model['texture_window']} px); there each pixel is, with probability {model['fraction']:g}, "
        "replaced by a wrong match: an integer disparity drawn uniformly from the scene's ground-truth "
        f"range (seed {model['seed']}).",
        f"- **Clicks**: per segment the exact end pixels and {clicks['extra']} more click pairs jittered "
        f"by a Gaussian of σ = {clicks['sigma_px']:g} px per coordinate, rounded to pixels (seed "
        f"{clicks['seed']}); each click pair is one measurement, its truth the segment's length.",
        "- Accuracy A = 100 − 100 |g − m| / g over the measurements where every method answered "
        "('failed' counts the others per method); 'within 5 %' is the share with A ≥ 95.",
        "",
        f"![segments]({plots['segments']})",
        "",
        report.markdown_table(
            ["scene", "size", "num_disparities", "SGBM valid", "SGBM within 1 px of GT", "outlier pixels (contended GT)", "segments"],
            [
                [
                    n,
                    f"{s['size'][0]}x{s['size'][1]}",
                    str(s["sgbm_config"]["num_disparities"]),
                    f"{100 * s['sgbm_valid_fraction']:.1f} %",
                    "–" if s["sgbm_within_1px"] is None else f"{100 * s['sgbm_within_1px']:.1f} %",
                    f"{100 * s['outlier_fraction']:.1f} %",
                    str(s["n_segments"]),
                ]
                for n, s in setup["scenes"].items()
            ],
        ),
        "",
    ]
    for cond in CONDITIONS:
        c = summary["conditions"][cond]
        ms = c["methods"]
        lines += [
            f"## {CONDITION_LABELS[cond]}",
            "",
            f"{c['n_common']} of {c['n_measurements']} measurements answered by every method. Median accuracy (mean ± std):",
            "",
            report.section(cond, report.markdown_table(
                ["method", "all", "within 5 %"] + names + ["failed", "gap flagged"],
                [
                    [
                        report.METHOD_LABELS[m],
                        f"**{f(ms[m]['overall']['median'])}** ({f(ms[m]['overall']['mean'])} ± {f(ms[m]['overall']['std'])})",
                        "–" if ms[m]["overall"]["within_5pct"] is None else f"{100 * ms[m]['overall']['within_5pct']:.1f} %",
                    ]
                    + [f(ms[m]["by_scene"][n]["median"]) for n in names]
                    + [str(ms[m]["failed"]), str(ms[m]["gap_detected"])]
                    for m in METHODS
                ],
            )),
            "",
            f"![median accuracy per scene]({plots[f'bars_{cond}']})",
            "",
            f"![signed errors]({plots[f'hist_{cond}']})",
            "",
        ]
    lines += ["Every segment and every method's answer is in `results.json` (`segments`).", ""]
    return "\n".join(lines)
