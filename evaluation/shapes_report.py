"""The shapes study's report: a Markdown table against the targets, one CSV row per case, results.json
and PNG plots (box errors against distance, 2σ coverage and verdicts), all in one folder."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evaluation import report
from evaluation.shapes import BANDS, DIMS, checks, summarize


def _v(x: float | None, pct: bool = False) -> str:
    if x is None:
        return "–"
    return f"{100 * x:.1f} %" if pct else f"{x:.2f}"


def shapes_markdown(summary: dict[str, Any], protocol: dict[str, Any]) -> str:
    """The report page: targets met or not, then per profile the bands, verdicts, heights and areas."""
    lines = ["# Shapes on the simulated rig", "",
             f"{protocol.get('boxes')} boxes and {protocol.get('panels')} panels per profile, seeds from {protocol.get('seed')}, "
             f"{protocol.get('width')}x{protocol.get('height')} px; wall time {protocol.get('wall_time_s', math.nan):.0f} s "
             "(evaluation/shapes.py).", "", "## Targets", ""]
    rows = [[p, name, "–" if v is None else f"{v:.3f}", limit, "yes" if ok else "**no**"] for p, name, v, limit, ok in checks(summary)]
    lines += [report.section("targets", report.markdown_table(["profile", "figure", "measured", "target", "met"], rows)), ""]
    for profile, s in summary.items():
        lines += [f"## Profile {profile}", "",
                  f"{s['boxes']} boxes, {s['full_view']} with the top face fully seen; median time per box {_v(s['box_ms_median'])} ms.", ""]
        band_rows = [[name, str(b["n"]), str(b["refused"]), *(_v(b[d]) for d in DIMS)] for name, b in s["bands"].items()]
        lines += [report.markdown_table(["distance", "boxes", "refused", "median abs. error L %", "W %", "H %"], band_rows), ""]
        c = s["cut_or_occluded"]
        lines += [f"- good answers with an error above 5 %: {s['good_above_5pct']} of {s['full_view']} fully seen boxes "
                  f"({_v(s['good_above_5pct_share'], True)}); {s['good']} good answers.",
                  f"- 2σ coverage of the good answers' dimensions: {_v(s['coverage_2sigma'], True)} of {s['coverage_dims']}.",
                  f"- cut or occluded boxes: {c['n']}: good {c['good']}, check {c['check']}, unreliable {c['unreliable']}, "
                  f"refused {c['refused']}.",
                  f"- height above the plane found under the click, 1-3 m: median abs. error {_v(s['height']['median_abs_err_pct'])} % "
                  f"over {s['height']['n']} ({s['height']['refused']} refused), 2σ coverage {_v(s['height']['coverage_2sigma'], True)}.",
                  f"- panel area: median abs. error {_v(s['area']['median_abs_err_pct'])} % over {s['area']['n']} "
                  f"({s['area']['refused']} refused), 2σ coverage {_v(s['area']['coverage_2sigma'], True)}.", ""]
    lines += ["Plots: box_errors.png (signed error of each dimension against distance, fully seen boxes), "
              "box_verdicts.png (verdicts of fully seen and cut/occluded boxes).", ""]
    return "\n".join(lines)


def write_csv(path: Path, records: Sequence[dict[str, Any]]) -> Path:
    """One row per case, the union of the records' fields."""
    fields = list(dict.fromkeys(k for r in records for k in r))
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        for r in records:
            w.writerow({k: r.get(k, "") for k in fields})
    return path


def _plots(out: Path, records: Sequence[dict[str, Any]]) -> list[Path]:
    plt = report.pyplot()
    profiles = list(dict.fromkeys(r["profile"] for r in records))
    fig, axes = plt.subplots(len(profiles), 3, figsize=(12, 3.4 * len(profiles)), squeeze=False)
    for i, p in enumerate(profiles):
        full = [r for r in records if r["kind"] == "box" and r["profile"] == p and r["full_view"]]
        for j, d in enumerate(DIMS):
            ax = axes[i, j]
            for q, colour in (("good", "C2"), ("check", "C1"), ("unreliable", "C3")):
                sel = [r for r in full if r["quality"] == q]
                ax.scatter([r["range_m"] for r in sel], [r[f"{d}_err_pct"] for r in sel], s=9, color=colour, label=q)
            for name, lo, hi in BANDS:
                limit = 1.5 if lo < 2.0 else 3.0
                ax.hlines([-limit, limit], lo, min(hi, 3.0), colors="k", lw=0.7, linestyles="--")
            ax.axhline(0, color="grey", lw=0.5)
            ax.set_ylim(-15, 15)
            ax.set_title(f"{p}: {d}", fontsize=9)
            ax.set_xlabel("distance (m)")
            ax.set_ylabel("error (%)")
            ax.grid(alpha=0.3)
        axes[i, 0].legend(fontsize=7)
    paths = [report.save(fig, out / "box_errors.png", "Box dimensions: signed error (dashed: the median targets)", dpi=100)]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    qs = ("good", "check", "unreliable", "refused")
    groups = [(p, seen) for p in profiles for seen in (True, False)]
    bottom = np.zeros(len(groups))
    for q, colour in zip(qs, ("C2", "C1", "C3", "grey")):
        n = np.array([sum(r["quality"] == q for r in records if r["kind"] == "box" and r["profile"] == p and r["full_view"] == seen)
                      for p, seen in groups], float)
        tot = np.array([max(1, sum(1 for r in records if r["kind"] == "box" and r["profile"] == p and r["full_view"] == seen))
                        for p, seen in groups], float)
        ax.bar(range(len(groups)), 100 * n / tot, bottom=bottom, color=colour, label=q)
        bottom += 100 * n / tot
    ax.set_xticks(range(len(groups)), [f"{p}\n{'fully seen' if seen else 'cut/occluded'}" for p, seen in groups], fontsize=8)
    ax.set_ylabel("% of boxes")
    ax.legend(fontsize=7)
    paths.append(report.save(fig, out / "box_verdicts.png", "Box verdicts", dpi=100))
    return paths


def write_shapes_report(out: Path, records: Sequence[dict[str, Any]], protocol: dict[str, Any]) -> dict[str, Path]:
    """report.md, shapes.csv, results.json and the plots in ``out``; their paths by name."""
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(records)
    (out / "report.md").write_text(shapes_markdown(summary, protocol))
    report.write_json(out / "results.json", {"kind": "shapes", "protocol": protocol, "summary": summary,
                                             "targets": [dict(zip(("profile", "figure", "measured", "target", "met"), c)) for c in checks(summary)]})
    paths = {"report": out / "report.md", "csv": write_csv(out / "shapes.csv", records), "results": out / "results.json"}
    for p in _plots(out, records):
        paths[p.stem] = p
    return paths
