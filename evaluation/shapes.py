"""The shapes study: boxes, heights and panel areas on the simulated rig against their truth.

Each box case (``sim.shapes.box_case``: a box of 10-80 cm per side at a random yaw, on a floor or a
table, 0.6-3 m from the camera, plain, cut by the image border or beside a second box) is measured
twice: ``measure.box.measure_box`` at the click on its top face, and ``measure.height.measure_height``
at the same click (the height above the plane found under it). Each panel case
(``sim.shapes.panel_case``: a framed board on a wall) is measured with ``measure.area.measure_area``
at its four clicked corners. Both simulator profiles ("stress", "paper") draw their own cases from
the same seeds. A case is one record (a flat dict); ``evaluation.shapes_report`` summarises them
against the targets and writes the table and plots.

A box is *fully seen* when at least ``FULL_VIEW`` of its top face is in the image and not hidden;
the others (cut by the border, hidden by the box beside it) should come out "check" or
"unreliable", or be refused.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from batch.executors import make_executor

PROFILES: tuple[str, ...] = ("stress", "paper")
FULL_VIEW = 0.95
DIMS: tuple[str, ...] = ("length", "width", "height")


@dataclass(frozen=True)
class ShapeJob:
    """One case to simulate and measure: ``kind`` "box" or "panel", its seed, profile and image size (px)."""

    kind: str
    seed: int
    profile: str
    width: int = 1280
    height: int = 720


def plan(boxes: int, panels: int, seed: int = 0, profiles: Sequence[str] = PROFILES,
         width: int = 1280, height: int = 720) -> list[ShapeJob]:
    """``boxes`` box cases and ``panels`` panel cases per profile, seeds ``seed``, ``seed + 1``, ..."""
    return [ShapeJob(kind, seed + i, p, width, height)
            for p in profiles for kind, n in (("box", boxes), ("panel", panels)) for i in range(n)]


def _err_pct(value: float, truth: float) -> float:
    return 100.0 * (value - truth) / truth if math.isfinite(value) else math.nan


def _box_record(job: ShapeJob) -> dict[str, Any]:
    from measure import MeasureError, measure_box, measure_height
    from sim.shapes import box_case

    case = box_case(job.seed, job.profile, width=job.width, height=job.height)
    truth = (case.length_m, case.width_m, case.height_m)
    rec: dict[str, Any] = {"kind": "box", "seed": job.seed, "profile": job.profile, "range_m": case.range_m,
                           "variant": case.variant, "support": case.support, "visible": case.visible,
                           "full_view": case.visible >= FULL_VIEW}
    rec |= {f"true_{d}_m": t for d, t in zip(DIMS, truth)}
    t0 = time.perf_counter()
    try:
        box = measure_box(case.frame, case.click_px)
        rec |= {"quality": box.quality, "reasons": "; ".join(box.reasons), "refused": ""}
        for d, v, s, t in zip(DIMS, box.dimensions_m, box.uncertainty_m, truth):
            rec |= {f"{d}_m": v, f"{d}_sigma_m": s, f"{d}_err_pct": _err_pct(v, t)}
    except MeasureError as exc:
        rec |= {"quality": "refused", "reasons": "", "refused": str(exc)}
        for d in DIMS:
            rec |= {f"{d}_m": math.nan, f"{d}_sigma_m": math.nan, f"{d}_err_pct": math.nan}
    rec["box_ms"] = (time.perf_counter() - t0) * 1000.0
    t0 = time.perf_counter()
    try:
        h = measure_height(case.frame, case.click_px)
        rec |= {"hgt_m": h.value, "hgt_sigma_m": h.uncertainty, "hgt_err_pct": _err_pct(h.value, case.height_m),
                "hgt_quality": h.quality}
    except MeasureError as exc:
        rec |= {"hgt_m": math.nan, "hgt_sigma_m": math.nan, "hgt_err_pct": math.nan, "hgt_quality": "refused"}
        rec["hgt_refused"] = str(exc)
    rec["hgt_ms"] = (time.perf_counter() - t0) * 1000.0
    return rec


def _panel_record(job: ShapeJob) -> dict[str, Any]:
    from measure import MeasureError, measure_area
    from sim.shapes import panel_case

    case = panel_case(job.seed, job.profile, width=job.width, height=job.height)
    rec: dict[str, Any] = {"kind": "panel", "seed": job.seed, "profile": job.profile, "range_m": case.range_m,
                           "true_area_m2": case.area_m2}
    t0 = time.perf_counter()
    try:
        a = measure_area(case.frame, case.clicks_px)
        rec |= {"area_m2": a.value, "area_sigma_m2": a.uncertainty, "area_err_pct": _err_pct(a.value, case.area_m2),
                "quality": a.quality, "reasons": "; ".join(a.reasons), "refused": ""}
    except MeasureError as exc:
        rec |= {"area_m2": math.nan, "area_sigma_m2": math.nan, "area_err_pct": math.nan, "quality": "refused",
                "reasons": "", "refused": str(exc)}
    rec["area_ms"] = (time.perf_counter() - t0) * 1000.0
    return rec


def run_job(job: ShapeJob) -> dict[str, Any]:
    """The record of one job (module docstring); the simulator's view caches are emptied after it (no
    two jobs share a view)."""
    from sim.sensor import clear_static_maps

    try:
        return _box_record(job) if job.kind == "box" else _panel_record(job)
    finally:
        clear_static_maps()


def run(jobs: Sequence[ShapeJob], workers: int = 1, on_result: Callable[[dict], None] | None = None) -> list[dict[str, Any]]:
    """Every job's record in job order, on ``workers`` processes (``batch.executors``)."""
    ex = make_executor(workers)
    done: dict[int, dict[str, Any]] = {}
    try:
        for i, rec in ex.imap(run_job, list(jobs)):
            done[i] = rec
            if on_result is not None:
                on_result(rec)
    finally:
        ex.close()
    return [done[i] for i in range(len(jobs))]


def _median_abs(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.median(np.abs(x))) if x.size else None


def _share(flags: np.ndarray) -> float | None:
    return float(np.mean(flags)) if flags.size else None


BANDS: tuple[tuple[str, float, float], ...] = (("0.6-2 m", 0.6, 2.0), ("2-3 m", 2.0, 3.0 + 1e-9))
HEIGHT_BAND = (1.0, 3.0 + 1e-9)


def summarize(records: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per profile: box errors by distance band, verdict honesty, 2σ coverage, cut/occluded verdicts,
    heights at 1-3 m and panel areas (all errors in %)."""
    out: dict[str, Any] = {}
    for profile in dict.fromkeys(r["profile"] for r in records):
        boxes = [r for r in records if r["kind"] == "box" and r["profile"] == profile]
        panels = [r for r in records if r["kind"] == "panel" and r["profile"] == profile]
        full = [r for r in boxes if r["full_view"]]
        rng = np.array([r["range_m"] for r in full])
        bands = {}
        for name, lo, hi in BANDS:
            sel = [r for r, x in zip(full, rng) if lo <= x < hi]
            bands[name] = {"n": len(sel), "refused": sum(r["quality"] == "refused" for r in sel)}
            for d in DIMS:
                bands[name][d] = _median_abs(np.array([r[f"{d}_err_pct"] for r in sel], float))
        good = [r for r in full if r["quality"] == "good"]
        bad_good = [r for r in good if max(abs(r[f"{d}_err_pct"]) for d in DIMS) > 5.0]
        z = np.array([abs(r[f"{d}_m"] - r[f"true_{d}_m"]) / r[f"{d}_sigma_m"] for r in good for d in DIMS], float)
        hidden = [r for r in boxes if not r["full_view"]]
        verdicts = {q: sum(r["quality"] == q for r in hidden) for q in ("good", "check", "unreliable", "refused")}
        hsel = [r for r in boxes if r["full_view"] and HEIGHT_BAND[0] <= r["range_m"] < HEIGHT_BAND[1]]
        herr = np.array([r["hgt_err_pct"] for r in hsel], float)
        hz = np.array([abs(r["hgt_m"] - r["true_height_m"]) / r["hgt_sigma_m"] for r in hsel if math.isfinite(r["hgt_m"])])
        aerr = np.array([r["area_err_pct"] for r in panels], float)
        az = np.array([abs(r["area_m2"] - r["true_area_m2"]) / r["area_sigma_m2"] for r in panels if math.isfinite(r["area_m2"])])
        out[profile] = {
            "boxes": len(boxes), "full_view": len(full), "bands": bands,
            "good": len(good), "good_above_5pct": len(bad_good),
            "good_above_5pct_share": len(bad_good) / len(full) if full else None,
            "coverage_2sigma": _share(z <= 2.0), "coverage_dims": int(z.size),
            "cut_or_occluded": {"n": len(hidden), **verdicts,
                                "not_good_share": (1 - verdicts["good"] / len(hidden)) if hidden else None},
            "height": {"n": len(hsel), "median_abs_err_pct": _median_abs(herr), "refused": int(np.isnan(herr).sum()),
                       "coverage_2sigma": _share(hz <= 2.0)},
            "area": {"n": len(panels), "median_abs_err_pct": _median_abs(aerr), "refused": int(np.isnan(aerr).sum()),
                     "coverage_2sigma": _share(az <= 2.0)},
            "box_ms_median": _median_abs(np.array([r["box_ms"] for r in boxes], float)),
        }
    return out


TARGETS = {"near_pct": 1.5, "far_pct": 3.0, "good_above_5pct_share": 0.02, "coverage_2sigma": 0.85,
           "cut_not_good_share": 1.0, "height_pct": 1.0, "area_pct": 2.0}


def checks(summary: dict[str, Any]) -> list[tuple[str, str, float | None, str, bool]]:
    """(profile, target, measured, limit, met) for every Done-when figure of the study."""
    rows = []
    for profile, s in summary.items():
        for band, key in (("0.6-2 m", "near_pct"), ("2-3 m", "far_pct")):
            for d in DIMS:
                v = s["bands"][band][d]
                rows.append((profile, f"box {d} median abs. error {band} (%)", v, f"<= {TARGETS[key]}", v is not None and v <= TARGETS[key]))
        v = s["good_above_5pct_share"]
        rows.append((profile, "good with error > 5 % (share of fully seen boxes)", v, "<= 0.02", v is not None and v <= TARGETS["good_above_5pct_share"]))
        v = s["coverage_2sigma"]
        rows.append((profile, "2σ coverage of good dimensions", v, ">= 0.85", v is not None and v >= TARGETS["coverage_2sigma"]))
        v = s["cut_or_occluded"]["not_good_share"]
        rows.append((profile, "cut/occluded boxes not good (share)", v, "= 1", v is not None and v >= TARGETS["cut_not_good_share"]))
        v = s["height"]["median_abs_err_pct"]
        rows.append((profile, "height median abs. error 1-3 m (%)", v, "<= 1.0", v is not None and v <= TARGETS["height_pct"]))
        v = s["area"]["median_abs_err_pct"]
        rows.append((profile, "panel area median abs. error (%)", v, "<= 2.0", v is not None and v <= TARGETS["area_pct"]))
    return rows
