"""Several frames of a still scene on the simulated rig: what pooling N frames buys, and
whether the stated uncertainty covers the truth as often as it claims.

Protocol: still scenes of the poster (indoor light, board 1 m in front of the wall) at 2, 3.5 and 5 m
(band "2-5 m") and at 6 and 7 m (band "6-7 m"). Each scene simulates 10 frames of one viewpoint (fresh
sensor noise, holes and, with ``contention="fresh"``, fresh contention outliers per frame; with
``"static"`` the contention pattern repeats in every frame, ``SensorModel.static_contention``); the
poster's width and its length are each clicked once in the newest frame: "human" clicks
(``sim.ClickModel``: 2.5 px jitter, a quarter of the taps up to 6 px off the board), measured with the
click error those taps have (``click_px`` = :func:`click_rms_px`, their rms along the segment), and
"exact" clicks on the true end pixels, measured with ``click_px=0``. ``measure.sequence`` measures the
newest N = 1, 3, 5, 10 frames. Reported per (band, contention, clicks, N): cases and scenes, mean
and std of A (Eq. 8), coverage of the truth by one sigma (nominal 68.3 %) and by the 95 % interval,
each with its Wilson 95 % interval, and mean sigma.

Each term against its truth (the simulator knows the board): the click error is the distance
between the clicked pixels' rays met with the true board minus the true length, the sensor error the
measured distance minus that; the reported sigma splits into its click part (``click_px`` times the
click term per pixel) and the rest. The table "Terms against their truth" gives how often each error
is within its part.

A moving scene must be refused: "pan" (the camera turns, the image moves 1 px a frame), "push" (the
camera walks 3 cm a frame towards the board), "turn" (the board turns 1 degree a frame): the answer
must come from the newest frame alone.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from evaluation import report
from evaluation.report import wilson
from batch.executors import make_executor
from measure import accuracy

BANDS: dict[str, tuple[float, ...]] = {"2-5 m": (2.0, 3.5, 5.0), "6-7 m": (6.0, 7.0)}
DISTANCES_M: tuple[float, ...] = tuple(d for ds in BANDS.values() for d in ds)
TARGETS: tuple[str, ...] = ("poster-width", "poster-length")
CONTENTION: tuple[str, ...] = ("fresh", "static")
CLICKS: tuple[str, ...] = ("human", "exact")
COUNTS: tuple[int, ...] = (1, 3, 5, 10)
MOTIONS: tuple[str, ...] = ("pan", "push", "turn")
ONE_SIGMA = math.erf(1 / math.sqrt(2))  # 0.683: what a one-sigma claims for a normal error


@dataclass(frozen=True)
class FramesJob:
    distance_m: float
    target: str  # the target whose truth ``trial_frames`` returns; a still job measures every one of TARGETS
    contention: str
    seed: int
    width: int = 1280
    height: int = 720
    motion: str | None = None  # None: a still scene; "pan" / "push" / "turn": a moving one


def click_rms_px(model) -> float:
    """Root mean square (px) of a ``sim.ClickModel`` tap's error along the segment: the jitter's
    component, the off-object step (with chance p, uniform on 1..L px: mean square (L³ - 1) / (3 (L - 1)))
    and the rounding to a whole pixel (1/12)."""
    big = model.off_object_px
    step2 = (big**3 - 1.0) / (3.0 * (big - 1.0)) if big > 1.0 else big * big
    return math.sqrt(model.jitter_px**2 + model.off_object_prob * step2 + 1.0 / 12.0)


def _clicks(truth, job: FramesJob, k: int):
    from sim.truth import ClickModel

    human = ClickModel().clicks(truth, np.random.default_rng([job.seed, 99 + k]), job.width, job.height)
    exact = ClickModel(jitter_px=0.0, off_object_prob=0.0).clicks(truth, np.random.default_rng(0), job.width, job.height)
    return {"human": human, "exact": exact}


def _params(job: FramesJob, i: int, n: int):
    from sim.scenes import SceneParams

    dz = 0.03 * (n - 1 - i) if job.motion == "push" else 0.0
    yaw = 1.0 * (n - 1 - i) if job.motion == "turn" else 0.0
    return SceneParams("poster", job.distance_m + dz, yaw, 0.0, job.width, job.height, mount="stand", standoff_m=1.0)


def trial_frames(job: FramesJob, n: int = 10):
    """``n`` frames of the job's scene (oldest first), the truth of ``job.target`` in the newest, and
    its (human, exact) clicks."""
    from sim.scenario import make_model, simulate_frame

    model = make_model("indoor", static_contention=job.contention == "static", static_seed=job.seed)
    frames, truth = [], None
    for i in range(n):
        f, t = simulate_frame(_params(job, i, n), model, np.random.default_rng([job.seed, i]), target=job.target, timestamp=i / 10.0)
        if job.motion == "pan":  # the camera turns: the image moves by a pixel a frame (the newest in place)
            k = n - 1 - i
            f = replace(f, image=np.roll(f.image, k, axis=1), disparity=np.roll(f.disparity, k, axis=1),
                        confidence=None if f.confidence is None else np.roll(f.confidence, k, axis=1))
        frames.append(f)
        truth = t  # the newest frame's truth: the answer is about the newest frame's clicks
    return frames, truth, _clicks(truth, job, TARGETS.index(job.target) if job.target in TARGETS else 0)


def board_distance(frame, truth, p1, p2) -> float:
    """Distance (m) between the rays of pixels ``p1``, ``p2`` met with the true board: inverse depth
    affine in (x, y) over the truth's pixels near the true segment within 5 % of its ends' depth (a
    plane), so a click off the board still lands on the board's plane."""
    from measure import ray

    a, b = np.array(truth.p1_px), np.array(truth.p2_px)
    z0 = 0.5 * (truth.p1_m[2] + truth.p2_m[2])
    h, w = truth.depth_m.shape
    ys, xs = np.mgrid[max(0, int(min(a[1], b[1])) - 8): min(h, int(max(a[1], b[1])) + 9),
                      max(0, int(min(a[0], b[0])) - 8): min(w, int(max(a[0], b[0])) + 9)]
    z = truth.depth_m[ys, xs]
    sel = np.isfinite(z) & (np.abs(z - z0) < 0.05 * z0)
    coef = np.linalg.lstsq(np.stack([xs[sel], ys[sel], np.ones(int(sel.sum()))], 1).astype(float), 1.0 / z[sel], rcond=None)[0]
    q = [ray(frame, x, y) / float(coef @ [x, y, 1.0]) for x, y in (p1, p2)]
    return float(np.linalg.norm(q[1] - q[0]))


def _job(job: FramesJob) -> dict[str, Any]:
    rec = asdict(job)
    rec["scene_m"] = rec.pop("distance_m")  # "distance_m" is the measured answer
    return rec


def _measure_still(frames, job: FramesJob) -> list[dict[str, Any]]:
    from measure import MeasureError, MeasureOptions, measure_sequence, robust_with_terms
    from sim.scenes import get_view
    from sim.truth import ClickModel

    view = get_view(_params(job, len(frames) - 1, len(frames)))
    out = []
    for k, target in enumerate(TARGETS):
        truth = view.truth(target)
        for kind, (p1, p2) in _clicks(truth, job, k).items():
            click_px = click_rms_px(ClickModel()) if kind == "human" else 0.0
            rec0 = {**_job(job), "target": target, "clicks": kind, "click_px": click_px, "truth_m": truth.length_m}
            try:
                click_term = robust_with_terms(frames[-1], p1, p2, MeasureOptions(click_px=click_px))[1].get("click", 0.0)
                board = board_distance(frames[-1], truth, p1, p2)
            except MeasureError as exc:
                out.append({**rec0, "n": 1, "error": str(exc)})
                continue
            for n in COUNTS:
                rec = {**rec0, "n": n}
                try:
                    m = measure_sequence(frames[len(frames) - n:], p1, p2, click_px=click_px)
                except MeasureError as exc:
                    out.append({**rec, "error": str(exc)})
                    continue
                lo, hi = m.interval_m
                err = m.distance_m - truth.length_m
                sensor_sigma = math.sqrt(max(0.0, m.uncertainty_m**2 - click_term**2))
                out.append({**rec, "distance_m": m.distance_m, "sigma_m": m.uncertainty_m, "single_sigma_m": m.single_frame_uncertainty_m,
                            "covered95": bool(lo <= truth.length_m <= hi), "covered1": bool(abs(err) <= m.uncertainty_m),
                            "click_err_m": board - truth.length_m, "click_sigma_m": click_term,
                            "sensor_err_m": m.distance_m - board, "sensor_sigma_m": sensor_sigma,
                            "frames_used": m.frames_used, "reasons": list(m.reasons), "quality": m.quality})
    return out


def _measure_moving(frames, clicks, truth, job: FramesJob) -> list[dict[str, Any]]:
    from measure import MeasureError, measure_sequence

    out = []
    for kind, (p1, p2) in clicks.items():
        rec = {**_job(job), "clicks": kind, "n": len(frames), "truth_m": truth.length_m}
        try:
            m = measure_sequence(frames, p1, p2)
        except MeasureError as exc:
            out.append({**rec, "error": str(exc)})
            continue
        out.append({**rec, "distance_m": m.distance_m, "frames_used": m.frames_used, "reasons": list(m.reasons)})
    return out


def run_job(job: FramesJob) -> list[dict[str, Any]]:
    """Every (target, clicks, N) measurement of one still scene, or the refusal check of a moving one."""
    frames, truth, clicks = trial_frames(job, max(COUNTS))
    return _measure_still(frames, job) if job.motion is None else _measure_moving(frames, clicks, truth, job)


def plan(trials: int = 85, near_trials: int = 20, seed: int = 0, moving: int = 4, width: int = 1280, height: int = 720) -> list[FramesJob]:
    """Still scenes: ``trials`` per (6-7 m distance, contention), ``near_trials`` per (2-5 m distance,
    contention), two targets and two click kinds each; ``moving`` sequences per motion at 7 m."""
    per = {d: (trials if d in BANDS["6-7 m"] else near_trials) for d in DISTANCES_M}
    jobs = [FramesJob(d, "poster-width", c, seed * 1_000_000 + 10_000 * i + k, width, height)
            for i, (d, c) in enumerate((d, c) for d in DISTANCES_M for c in CONTENTION) for k in range(per[d])]
    jobs += [FramesJob(7.0, "poster-width", "fresh", seed * 1_000_000 + 900_000 + 100 * j + k, width, height, motion=m)
             for j, m in enumerate(MOTIONS) for k in range(moving)]
    return jobs


def run(jobs: Sequence[FramesJob], workers: int = 1) -> list[dict[str, Any]]:
    """All jobs' records in job order, on ``workers`` processes (batch.executors)."""
    ex = make_executor(workers)
    try:
        done = dict(ex.imap(run_job, list(jobs)))
    finally:
        ex.close()
    return [r for i in range(len(jobs)) for r in done[i]]


def _rate(flags: Sequence[bool]) -> dict[str, Any]:
    k, n = int(sum(flags)), len(flags)
    lo, hi = wilson(k, n)
    return {"k": k, "n": n, "rate": k / n if n else None, "ci": [lo, hi]}


def _cell(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if "distance_m" in r]
    a = accuracy(np.array([r["truth_m"] for r in ok]), np.array([r["distance_m"] for r in ok])) if ok else np.array([])
    return {
        "n": len(ok), "errors": len(rows) - len(ok), "scenes": len({(r["seed"], r["contention"]) for r in ok}),
        "mean_A": float(a.mean()) if a.size else None,
        "std_A": float(a.std(ddof=1)) if a.size > 1 else None,
        "coverage1": _rate([r["covered1"] for r in ok]), "coverage95": _rate([r["covered95"] for r in ok]),
        "click_within": _rate([abs(r["click_err_m"]) <= r["click_sigma_m"] for r in ok if r["click_sigma_m"] > 0]),
        "sensor_within": _rate([abs(r["sensor_err_m"]) <= r["sensor_sigma_m"] for r in ok]),
        "sigma_pct": float(np.mean([100 * r["sigma_m"] / r["truth_m"] for r in ok])) if ok else None,
        "click_err_pct": float(np.sqrt(np.mean([(100 * r["click_err_m"] / r["truth_m"]) ** 2 for r in ok]))) if ok else None,
        "click_sigma_pct": float(np.mean([100 * r["click_sigma_m"] / r["truth_m"] for r in ok])) if ok else None,
        "sensor_err_pct": float(np.sqrt(np.mean([(100 * r["sensor_err_m"] / r["truth_m"]) ** 2 for r in ok]))) if ok else None,
        "sensor_sigma_pct": float(np.mean([100 * r["sensor_sigma_m"] / r["truth_m"] for r in ok])) if ok else None,
        "frames_used": float(np.mean([r["frames_used"] for r in ok])) if ok else None,
    }


def _key(band: str, contention: str, clicks: str, n: int) -> str:
    return f"{band}|{contention}|{clicks}|{n}"


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    still = [r for r in records if r["motion"] is None]
    cells = {}
    for band, ds in tuple(BANDS.items()) + tuple((f"{d:g} m", (d,)) for d in DISTANCES_M):
        for c in CONTENTION + ("both",):
            for k in CLICKS:
                for n in COUNTS:
                    rows = [r for r in still if r["n"] == n and r["clicks"] == k and (c == "both" or r["contention"] == c) and r["scene_m"] in ds]
                    cells[_key(band, c, k, n)] = _cell(rows)
    moving = [r for r in records if r["motion"] is not None]
    refused = [r for r in moving if r.get("frames_used") == 1 and any(x.startswith("scene moved") for x in r.get("reasons", []))]
    return {"cells": cells, "moving": {"n": len(moving), "refused": len(refused), "pooled_frames": [r.get("frames_used") for r in moving]}}



def _pct(rate: dict[str, Any]) -> str:
    if not rate["n"]:
        return "-"
    lo, hi = rate["ci"]
    return f"{100 * rate['rate']:.0f} % ({100 * lo:.0f}-{100 * hi:.0f})"


def frames_markdown(summary: dict[str, Any], protocol: dict[str, Any]) -> str:
    """report.md from the study's ``summary`` (:func:`summarize`) and ``protocol``; the tables between
    snippet markers "coverage" and "terms"."""
    cells = summary["cells"]
    cover = ["| distances | contention | clicks | N | cases (scenes) | mean A | std A | 1σ coverage | 95 % coverage | mean σ (%) | frames used |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for band in tuple(BANDS) + tuple(f"{d:g} m" for d in DISTANCES_M):
        for c in ("both",) + CONTENTION:
            for k in CLICKS:
                for n in COUNTS:
                    s = cells[_key(band, c, k, n)]
                    if s["n"]:
                        cover.append(f"| {band} | {c} | {k} | {n} | {s['n']} ({s['scenes']}) | {s['mean_A']:.2f} | {s['std_A'] or 0:.2f} | "
                                     f"{_pct(s['coverage1'])} | {_pct(s['coverage95'])} | {s['sigma_pct']:.2f} | {s['frames_used']:.1f} |")
    terms = ["| distances | clicks | N | click error rms | click σ | within | sensor error rms | sensor σ | within |",
             "|---|---|---|---|---|---|---|---|---|"]
    for band in BANDS:
        for k in CLICKS:
            for n in COUNTS:
                s = cells[_key(band, "both", k, n)]
                if s["n"]:
                    terms.append(f"| {band} | {k} | {n} | {s['click_err_pct']:.2f} | {s['click_sigma_pct']:.2f} | {_pct(s['click_within'])} | "
                                 f"{s['sensor_err_pct']:.2f} | {s['sensor_sigma_pct']:.2f} | {_pct(s['sensor_within'])} |")
    mv = summary["moving"]
    lines = ["# Several frames of a still scene (simulated rig)", "", __doc__.split("\n\n", 1)[1].strip(), "",
             f"Scenes: {protocol.get('trials')} per (6-7 m distance, contention), {protocol.get('near_trials')} per (2-5 m distance, "
             f"contention), seed {protocol.get('seed', 0)}; human clicks measured with click_px = {protocol.get('click_px', math.nan):.2f}; "
             f"wall time {protocol.get('wall_time_s', 0):.0f} s ({protocol.get('workers', 1)} workers). "
             "Coverage in brackets: Wilson 95 % interval of the rate; cases of one scene (two targets) share its frames.", "",
             "## Coverage and spread", "", report.section("coverage", "\n".join(cover)),
             "", "## Terms against their truth (both contention kinds)", "",
             "rms error and mean stated part (% of the length), and how often the error is within its part (nominal 68 %).", "",
             report.section("terms", "\n".join(terms)),
             "", "## Moving scenes", "", f"{mv['refused']} of {mv['n']} moving 10-frame cases ({mv['n'] // len(CLICKS)} sequences x "
             f"{len(CLICKS)} click kinds) refused (answer from the newest frame alone, with a \"scene moved\" reason); "
             f"frames pooled: {mv['pooled_frames']}.", ""]
    return "\n".join(lines)


def write_report(out: Path, records: list[dict[str, Any]], protocol: dict[str, Any]) -> dict[str, Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(records)
    cells = summary["cells"]
    (out / "report.md").write_text(frames_markdown(summary, protocol))
    (out / "results.json").write_text(json.dumps({"protocol": protocol, "summary": summary}, indent=1))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for k, style in zip(CLICKS, ("-", "--")):
        for d in DISTANCES_M:
            ys = [cells[_key(f"{d:g} m", "both", k, n)]["std_A"] for n in COUNTS]
            axes[0].plot(COUNTS, [math.nan if y is None else y for y in ys], style, marker="o", label=f"{d:g} m, {k} clicks")
        for band, marker in zip(BANDS, ("o", "s")):
            for key, colour in (("coverage1", "C0"), ("coverage95", "C3")):
                r = [cells[_key(band, "both", k, n)][key] for n in COUNTS]
                y = np.array([100 * (x["rate"] if x["n"] else math.nan) for x in r])
                err = np.clip(np.array([[100 * (x["rate"] - x["ci"][0]), 100 * (x["ci"][1] - x["rate"])] if x["n"] else [0, 0] for x in r]).T, 0, None)
                axes[1].errorbar(np.array(COUNTS) + (0.15 if k == "exact" else -0.15), y, yerr=err, fmt=style, marker=marker, color=colour,
                                 alpha=0.8, label=f"{band}, {k}, {'1σ' if key == 'coverage1' else '95 %'}")
    axes[0].set_title("spread: std of A")
    axes[0].set_ylabel("std of A (points)")
    axes[1].axhline(100 * ONE_SIGMA, color="C0", lw=0.8)
    axes[1].axhline(95, color="C3", lw=0.8)
    axes[1].set_title("coverage of the truth (Wilson 95 % bars)")
    axes[1].set_ylabel("%")
    for ax in axes:
        ax.set_xlabel("frames pooled N")
        ax.set_xticks(COUNTS)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6)
    report.save(fig, out / "frames.png", dpi=110)
    return {"report": out / "report.md", "plot": out / "frames.png", "results": out / "results.json"}
