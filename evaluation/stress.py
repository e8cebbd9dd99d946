"""Stress figures shared by the Middlebury and simulated stress protocols: clicks as people make them.

Each case is one click pair with a true length; it is measured by ``robust`` (the default, with its
uncertainty, 95 % interval and verdict) and ``basic``. Per condition the summary gives: share
answered, median and mean accuracy A (Eq. 8), share with A < 90, 1σ / 2σ / interval coverage of the
truth, share "good", share "good" with A < 90 (of all cases), 2σ coverage among "good", the gap
detector's firing rate (a false-positive rate on no-gap cases, a detection rate on gap cases), and the
share where robust is much worse than basic (robust A < 90 while basic A >= 90).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from evaluation import report
from measure import accuracy


@dataclass(frozen=True)
class StressCase:
    """One click pair to measure: pixels (x, y), true length (m), whether the truth is a gap."""

    group: str  # scene (Middlebury) or scene family (sim)
    condition: str
    p1_px: tuple[float, float]
    p2_px: tuple[float, float]
    truth_m: float
    is_gap: bool = False


@dataclass(frozen=True)
class StressRecord:
    case: StressCase
    disparity: str  # disparity source (Middlebury) or "sim"
    robust_m: float  # NaN when robust raised
    sigma_m: float
    lo_m: float
    hi_m: float
    quality: str  # "" when robust raised
    reasons: tuple[str, ...]
    gap: bool
    fit: str
    basic_m: float
    error: str = ""


def measure_case(frame: Any, case: StressCase, disparity: str, options: Any = None) -> StressRecord:
    """``robust`` and ``basic`` on one click pair, with ``options`` (a MeasureOptions; None = the defaults)
    but for the method; a MeasureError is a record without an answer."""
    from measure import MeasureError, MeasureOptions, measure_distance

    options = options or MeasureOptions()
    try:
        b = measure_distance(frame, case.p1_px, case.p2_px, replace(options, method="basic")).distance_m
    except MeasureError:
        b = math.nan
    try:
        m = measure_distance(frame, case.p1_px, case.p2_px, options)
    except MeasureError as exc:
        return StressRecord(case, disparity, math.nan, math.nan, math.nan, math.nan, "", (), False, "none", b, str(exc))
    return StressRecord(
        case, disparity, float(m.distance_m), float(m.uncertainty_m), float(m.interval_m[0]), float(m.interval_m[1]),
        m.quality, tuple(m.reasons), bool(m.gap_detected), m.fit, float(b),
    )


def _share(mask: np.ndarray, of: int) -> float | None:
    return float(mask.sum() / of) if of else None


def figures(records: Sequence[StressRecord]) -> dict[str, Any]:
    """The per-condition figures of the module docstring for ``records``."""
    n = len(records)
    if n == 0:
        return {"n": 0}
    g = np.array([r.case.truth_m for r in records])
    m = np.array([r.robust_m for r in records])
    s = np.array([r.sigma_m for r in records])
    lo = np.array([r.lo_m for r in records])
    hi = np.array([r.hi_m for r in records])
    b = np.array([r.basic_m for r in records])
    ok = np.isfinite(m)
    a = accuracy(g, m)
    ab = accuracy(g, b)
    err = np.abs(m - g)
    good = np.array([r.quality == "good" for r in records])
    gap = np.array([r.gap for r in records])
    is_gap = np.array([r.case.is_gap for r in records])
    acc = a[ok]
    with np.errstate(invalid="ignore"):
        cov1 = ok & (err <= s)
        cov2 = ok & (err <= 2 * s)
        inside = ok & (lo <= g) & (g <= hi)
        bad = ok & (a < 90)
        worse = ok & (a < 90) & np.isfinite(ab) & (ab >= 90)
    na = int(ok.sum())
    ng = int(good.sum())
    return {
        "n": n,
        "answered": na / n,
        "median_A": float(np.median(acc)) if na else None,
        "mean_A": float(acc.mean()) if na else None,
        "share_A_below_90": _share(bad, na),
        "cov_1sigma": _share(cov1, na),
        "cov_2sigma": _share(cov2, na),
        "cov_interval": _share(inside, na),
        "good": _share(good, n),
        "good_and_A_below_90": _share(good & bad, n),
        "cov_2sigma_among_good": _share(good & cov2, ng),
        "gap_rate_no_gap": _share(gap & ~is_gap, int((~is_gap).sum())),
        "gap_rate_gap": _share(gap & is_gap, int(is_gap.sum())),
        "robust_much_worse_than_basic": _share(worse, n),
        "basic_mean_A": float(np.nanmean(ab)) if np.isfinite(ab).any() else None,
        "unreliable": _share(np.array([r.quality == "unreliable" for r in records]), n),
    }


def by_condition(records: Sequence[StressRecord], key=lambda r: (r.disparity, r.case.condition), totals: bool = True) -> dict[str, dict[str, Any]]:
    """``figures`` per key (default: disparity / condition) and, with ``totals``, per disparity over all
    conditions ("all")."""
    out: dict[str, dict[str, Any]] = {}
    for k in dict.fromkeys(key(r) for r in records):
        out["/".join(k)] = figures([r for r in records if key(r) == k])
    for d in dict.fromkeys(r.disparity for r in records) if totals else ():
        out[f"{d}/all"] = figures([r for r in records if r.disparity == d])
    return out


def by_scene(records: Sequence[StressRecord]) -> dict[str, dict[str, Any]]:
    """``figures`` per disparity / scene (the case's group) over all its conditions."""
    return by_condition(records, key=lambda r: (r.disparity, r.case.group), totals=False)


def worst_scene(scenes: dict[str, dict[str, Any]], disparity: str, figure: str = "good_and_A_below_90") -> tuple[str, float] | None:
    """The scene of ``by_scene`` figures with the largest ``figure`` under ``disparity``, and that value."""
    rows = [(name.split("/", 1)[1], f[figure]) for name, f in scenes.items()
            if name.startswith(f"{disparity}/") and f.get(figure) is not None]
    return max(rows, key=lambda row: row[1]) if rows else None


COLUMNS: tuple[tuple[str, str], ...] = (
    ("n", "n"),
    ("answered", "answered"),
    ("median_A", "median A"),
    ("mean_A", "mean A"),
    ("share_A_below_90", "A<90"),
    ("cov_1sigma", "1σ cov"),
    ("cov_2sigma", "2σ cov"),
    ("good", "good"),
    ("good_and_A_below_90", "good & A<90"),
    ("cov_2sigma_among_good", "2σ cov among good"),
    ("gap_rate_no_gap", "gap FP"),
    ("gap_rate_gap", "gap found"),
    ("robust_much_worse_than_basic", "robust≪basic"),
    ("basic_mean_A", "basic mean A"),
)
_PCT = {"answered", "share_A_below_90", "cov_1sigma", "cov_2sigma", "good", "good_and_A_below_90", "cov_2sigma_among_good",
        "gap_rate_no_gap", "gap_rate_gap", "robust_much_worse_than_basic"}


def table(figs: dict[str, dict[str, Any]]) -> str:
    def cell(k: str, v: Any) -> str:
        if v is None:
            return "–"
        if k == "n":
            return str(v)
        return f"{100 * v:.1f} %" if k in _PCT else f"{v:.2f}"

    return report.markdown_table(["condition"] + [label for _, label in COLUMNS],
                                 [[name] + [cell(k, f.get(k)) for k, _ in COLUMNS] for name, f in figs.items()])


def plot_figures(path: Path, figs: dict[str, dict[str, Any]], title: str) -> Path:
    """Bars per condition: share A<90, 2σ coverage, share good, good & A<90."""
    plt = report.pyplot()
    names = list(figs)
    keys = (("share_A_below_90", "A < 90", "#d62728"), ("cov_2sigma", "2σ coverage", "#1f77b4"),
            ("good", "good", "#2ca02c"), ("good_and_A_below_90", "good & A < 90", "#ff7f0e"))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.75 * len(names) + 2), 3.6), dpi=90)
    x = np.arange(len(names))
    w = 0.2
    for i, (k, label, colour) in enumerate(keys):
        ax.bar(x + (i - 1.5) * w, [100 * (figs[n].get(k) or 0.0) for n in names], w, label=label, color=colour)
    ax.axhline(95, color="#1f77b4", lw=0.6, ls=":")
    ax.axhline(5, color="#ff7f0e", lw=0.6, ls=":")
    ax.set_xticks(x, names, rotation=35, ha="right", fontsize=7)
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, ncol=4, loc="upper center")
    return report.save(fig, path)


def record_json(r: StressRecord) -> dict[str, Any]:
    def num(x: float) -> float | None:
        return float(x) if math.isfinite(x) else None

    return {
        **asdict(r.case), "disparity": r.disparity, "robust_m": num(r.robust_m), "sigma_m": num(r.sigma_m),
        "interval_m": [num(r.lo_m), num(r.hi_m)], "quality": r.quality, "reasons": list(r.reasons), "gap": r.gap,
        "fit": r.fit, "basic_m": num(r.basic_m), "error": r.error,
    }


def write_stress_report(out_dir: Path, title: str, setup: dict[str, Any], splits: dict[str, Iterable[StressRecord]], notes: Sequence[str],
                        scenes: bool = False) -> dict[str, Path]:
    """report.md (a table per split, e.g. dev / held-out, and with ``scenes`` one per scene), one PNG per
    split, results.json."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    data: dict[str, Any] = {"setup": setup, "splits": {}}
    for split, recs in splits.items():
        recs = list(recs)
        figs = by_condition(recs)
        paths[split] = plot_figures(out_dir / f"stress_{split}.png", figs, f"{title}: {split}")
        data["splits"][split] = {"figures": figs, "records": [record_json(r) for r in recs]}
        if scenes:
            data["splits"][split]["scenes"] = by_scene(recs)
    report.write_json(out_dir / "results.json", data)
    (out_dir / "report.md").write_text(stress_markdown(title, notes, data))
    paths["report"] = out_dir / "report.md"
    return paths


def stress_markdown(title: str, notes: Sequence[str], data: dict[str, Any]) -> str:
    """report.md of a stress study from its results.json ``data``: the notes, then per split its
    table (between snippet markers named after the split), its plot and, when recorded, its per-scene
    table (markers ``<split>-scenes``) with the worst scene of each disparity."""
    lines = [f"# {title}", "", *notes, ""]
    for split, d in data["splits"].items():
        lines += [f"## {split} ({len(d['records'])} cases)", "", report.section(split, table(d["figures"])), "",
                  f"![{split}](stress_{split}.png)", ""]
        if "scenes" in d:
            worst = [(disp, worst_scene(d["scenes"], disp)) for disp in dict.fromkeys(r["disparity"] for r in d["records"])]
            said = "; ".join(f"{disp} {w[0]} ({100 * w[1]:.1f} %)" for disp, w in worst if w)
            lines += [f"### {split}: per scene", "", f"Worst scene by good & A<90: {said}.", "",
                      report.section(f"{split}-scenes", table(d["scenes"])), ""]
    return "\n".join(lines)
