"""Several frames of a still scene on the simulated rig (issue #17): what pooling N frames buys.

Protocol: the poster's width and length at 2, 4, 6 and 7 m (indoor light, board 1 m in front of the
wall), ``trials`` still scenes per cell. Each trial simulates 10 frames of one viewpoint (fresh sensor
noise, holes and, with ``contention="fresh"``, fresh contention outliers per frame; with ``"static"``
the contention pattern repeats in every frame, ``SensorModel.static_contention``) and clicks once:
"human" clicks (``sim.ClickModel``: 2.5 px jitter, a quarter of the taps up to 6 px off the board) and
"exact" clicks on the true end pixels (what the frames alone can buy). ``measure.sequence`` measures
the first N = 1, 3, 5, 10 frames (the N-th is the newest) with both pools. Reported per cell: mean
and std of A (Eq. 8), coverage of the truth by the 95 % interval and by one sigma, mean sigma and
frames used. A moving scene must be refused: "pan" (the camera turns, the image moves 1 px a
frame), "push" (the camera walks 3 cm a frame towards the board), "turn" (the board turns 1 degree a
frame): the answer must come from the newest frame alone.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from .report import accuracy

DISTANCES_M: tuple[float, ...] = (2.0, 4.0, 6.0, 7.0)
TARGETS: tuple[str, ...] = ("poster-width", "poster-length")
CONTENTION: tuple[str, ...] = ("fresh", "static")
CLICKS: tuple[str, ...] = ("human", "exact")
COUNTS: tuple[int, ...] = (1, 3, 5, 10)
MOTIONS: tuple[str, ...] = ("pan", "push", "turn")


@dataclass(frozen=True)
class FramesJob:
    distance_m: float
    target: str
    contention: str
    seed: int
    width: int = 1280
    height: int = 720
    motion: str | None = None  # None: a still scene; "pan" / "push": a moving camera


def trial_frames(job: FramesJob, n: int = 10):
    """``n`` frames of the job's scene (oldest first), its truth, and (human, exact) clicks."""
    from sim.scenario import make_model, simulate_frame
    from sim.scenes import SceneParams
    from sim.truth import ClickModel

    model = make_model("indoor", static_contention=job.contention == "static", static_seed=job.seed)
    frames, truth = [], None
    for i in range(n):
        dz = 0.03 * (n - 1 - i) if job.motion == "push" else 0.0
        yaw = 1.0 * (n - 1 - i) if job.motion == "turn" else 0.0
        params = SceneParams("poster", job.distance_m + dz, yaw, 0.0, job.width, job.height, mount="stand", standoff_m=1.0)
        f, t = simulate_frame(params, model, np.random.default_rng([job.seed, i]), target=job.target, timestamp=i / 10.0)
        if job.motion == "pan":  # the camera turns: the image moves by a pixel a frame (the newest in place)
            k = n - 1 - i
            f = replace(f, image=np.roll(f.image, k, axis=1), disparity=np.roll(f.disparity, k, axis=1),
                        confidence=None if f.confidence is None else np.roll(f.confidence, k, axis=1))
        frames.append(f)
        truth = t  # the newest frame's truth: the answer is about the newest frame's clicks
    human = ClickModel().clicks(truth, np.random.default_rng([job.seed, 99]), job.width, job.height)
    exact = ClickModel(jitter_px=0.0, off_object_prob=0.0).clicks(truth, np.random.default_rng(0), job.width, job.height)
    return frames, truth, {"human": human, "exact": exact}


def run_job(job: FramesJob) -> list[dict[str, Any]]:
    """Every (clicks, N, pool) measurement of one still trial, or the refusal check of a moving one."""
    from measure import MeasureError
    from measure.sequence import POOLS, measure_sequence

    n_max = max(COUNTS)
    frames, truth, clicks = trial_frames(job, n_max)
    out = []
    for kind, (p1, p2) in clicks.items():
        for n in (COUNTS if job.motion is None else (n_max,)):
            newest_truth = truth.length_m
            for pool in POOLS if n > 1 else POOLS[:1]:
                rec = {**asdict(job), "job_distance": job.distance_m, "clicks": kind, "n": n, "pool": pool, "truth_m": newest_truth}
                try:
                    m = measure_sequence(frames[:n], p1, p2, pool=pool)
                except MeasureError as exc:
                    out.append({**rec, "error": str(exc)})
                    continue
                lo, hi = m.interval_m
                out.append({**rec, "distance_m": m.distance_m, "sigma_m": m.uncertainty_m, "single_sigma_m": m.single_frame_uncertainty_m,
                            "covered95": bool(lo <= newest_truth <= hi), "covered1": bool(abs(m.distance_m - newest_truth) <= m.uncertainty_m),
                            "frames_used": m.frames_used, "reasons": list(m.reasons), "quality": m.quality})
    return out


def plan(trials: int, seed: int = 0, width: int = 1280, height: int = 720) -> list[FramesJob]:
    jobs = [FramesJob(d, t, c, seed * 100_000 + 1000 * i + k, width, height)
            for i, (d, t, c) in enumerate((d, t, c) for d in DISTANCES_M for t in TARGETS for c in CONTENTION) for k in range(trials)]
    jobs += [FramesJob(7.0, "poster-width", "fresh", seed * 100_000 + 90_000 + k, width, height, motion=m)
             for m in MOTIONS for k in range(max(1, trials // 2))]
    return jobs


def run(jobs: Sequence[FramesJob], workers: int = 1) -> list[dict[str, Any]]:
    if workers <= 1:
        return [r for j in jobs for r in run_job(j)]
    with ProcessPoolExecutor(workers) as ex:
        return [r for rs in ex.map(run_job, jobs, chunksize=2) for r in rs]


def _cell(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if "distance_m" in r]
    a = accuracy(np.array([r["truth_m"] for r in ok]), np.array([r["distance_m"] for r in ok])) if ok else np.array([])
    def mean(key):
        return float(np.mean([float(r[key]) for r in ok])) if ok else None
    return {
        "n": len(ok), "errors": len(rows) - len(ok),
        "mean_A": float(a.mean()) if a.size else None,
        "std_A": float(a.std(ddof=1)) if a.size > 1 else None,
        "coverage95": mean("covered95"), "coverage1": mean("covered1"),
        "sigma_pct": float(np.mean([100 * r["sigma_m"] / r["truth_m"] for r in ok])) if ok else None,
        "frames_used": mean("frames_used"),
    }


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    still = [r for r in records if r["motion"] is None]
    cells = {}
    for c in CONTENTION:
        for k in CLICKS:
            for band, ds in (("2-4 m", (2.0, 4.0)), ("6-7 m", (6.0, 7.0))) + tuple((f"{d:g} m", (d,)) for d in DISTANCES_M):
                for n in COUNTS:
                    for pool in ("samples", "fits"):
                        rows = [r for r in still if r["contention"] == c and r["clicks"] == k and r["job_distance"] in ds
                                and r["n"] == n and (r["pool"] == pool or n == 1)]
                        cells[f"{c}|{k}|{band}|{n}|{pool}"] = _cell(rows)
    moving = [r for r in records if r["motion"] is not None and r["pool"] == "samples"]  # one per (sequence, clicks)
    refused = [r for r in moving if r.get("frames_used") == 1 and any(x.startswith("scene moved") for x in r.get("reasons", []))]
    return {"cells": cells, "moving": {"n": len(moving), "refused": len(refused),
                                       "pooled_frames": [r.get("frames_used") for r in moving]}}


def write_report(out: Path, records: list[dict[str, Any]], protocol: dict[str, Any]) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(records)
    cells = summary["cells"]
    lines = ["# Several frames of a still scene (simulated rig)", "", __doc__.split("\n\n", 1)[1].strip(), "",
             f"Trials per (distance, target, contention) cell: {protocol['trials']}; wall time {protocol.get('wall_time_s', 0):.0f} s.", ""]
    for c in CONTENTION:
        for k in CLICKS:
            lines += [f"## contention {c}, {k} clicks", "",
                      "| distances | N | pool | mean A | std A | 95 % coverage | 1σ coverage | mean σ (%) | frames used | n |",
                      "|---|---|---|---|---|---|---|---|---|---|"]
            for band in ("2-4 m", "6-7 m") + tuple(f"{d:g} m" for d in DISTANCES_M):
                for n in COUNTS:
                    for pool in (("samples", "fits") if n > 1 else ("samples",)):
                        s = cells[f"{c}|{k}|{band}|{n}|{pool}"]
                        if not s["n"]:
                            continue
                        lines.append(f"| {band} | {n} | {pool if n > 1 else '-'} | {s['mean_A']:.2f} | {s['std_A'] or 0:.2f} | "
                                     f"{100 * s['coverage95']:.0f} % | {100 * s['coverage1']:.0f} % | {s['sigma_pct']:.2f} | {s['frames_used']:.1f} | {s['n']} |")
            lines.append("")
    mv = summary["moving"]
    lines += ["## moving scenes", "", f"{mv['refused']} of {mv['n']} moving 10-frame cases ({mv['n'] // len(CLICKS)} sequences x "
              f"{len(CLICKS)} click kinds) refused (answer from the newest frame alone, with a \"scene moved\" reason); "
              f"frames pooled: {mv['pooled_frames']}.", ""]
    (out / "report.md").write_text("\n".join(lines))
    (out / "results.json").write_text(json.dumps({"protocol": protocol, "summary": summary}, indent=1))
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, c in zip(axes, CONTENTION):
        for k, style in zip(CLICKS, ("-", "--")):
            for d in DISTANCES_M:
                ys = [cells[f"{c}|{k}|{d:g} m|{n}|samples"]["std_A"] for n in COUNTS]
                ax.plot(COUNTS, [math.nan if y is None else y for y in ys], style, marker="o", label=f"{d:g} m, {k} clicks")
        ax.set_title(f"contention {c}")
        ax.set_xlabel("frames pooled N")
        ax.set_xticks(COUNTS)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("std of A (points)")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "frames.png", dpi=110)
    plt.close(fig)
    return {"report": out / "report.md", "plot": out / "frames.png", "results": out / "results.json"}
