"""Accuracy statistics, plots and Markdown tables shared by the evaluation reports.

Accuracy of one measurement is the paper's Eq. 8 (docs/method.md "Results to beat"):
``A = 100 - 100 |g - m| / g`` with g the ground-truth length and m the measured one (same unit).
A is not clipped: a measurement three times too long scores -200, as it would in the paper.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

METHODS: tuple[str, ...] = ("basic", "paper", "robust", "z_only")
METHOD_LABELS: dict[str, str] = {
    "basic": "basic (window median)",
    "paper": "paper (robust PCA)",
    "robust": "robust (ours)",
    "z_only": "robust fit of Z alone",
}
METHOD_COLOURS: dict[str, str] = {"basic": "#9e9e9e", "paper": "#1f77b4", "robust": "#2ca02c", "z_only": "#ff7f0e"}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class EvalError(ValueError):
    """Bad evaluation arguments; the message says what to change."""


def summary(values: np.ndarray) -> dict[str, float | int | None]:
    """Mean, sample standard deviation, median, share within 5 % of the truth (A >= 95) and count
    of accuracies; None where undefined."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"mean": None, "std": None, "median": None, "within_5pct": None, "n": 0}
    return {
        "mean": float(v.mean()),
        "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
        "median": float(np.median(v)),
        "within_5pct": float(np.mean(v >= 95.0)),
        "n": int(v.size),
    }


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k / n (95 % for z = 1.96)."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - half), min(1.0, c + half)


def timing_summary(ms: np.ndarray) -> dict[str, float | int | None]:
    """Median, 95th percentile and worst of run times in milliseconds."""
    v = np.asarray(ms, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"median": None, "p95": None, "worst": None, "n": 0}
    return {
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95)),
        "worst": float(v.max()),
        "n": int(v.size),
    }


def grouped(keys: Sequence[str], values: np.ndarray, order: Sequence[str]) -> dict[str, dict[str, Any]]:
    """``summary`` of ``values`` for each key in ``order`` (keys[i] labels values[i])."""
    k = np.asarray(keys)
    return {key: summary(values[k == key]) for key in order}


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2, allow_nan=False, default=_json_default) + "\n")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def fmt(x: float | None, digits: int = 2) -> str:
    return "–" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(" --- " for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def save(fig: Any, path: Path, title: str | None = None, **savefig: Any) -> Path:
    """Lay out, write and close a matplotlib figure: its title (10 pt) when given, a tight layout,
    the PNG at ``path`` (``savefig`` keywords passed on, e.g. dpi)."""
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, **savefig)
    pyplot().close(fig)
    return path


def section(name: str, text: str) -> str:
    """``text`` between snippet markers, so a page of the manual can include it by name
    (``--8<-- "docs/eval/sim/report.md:summary"``, the pymdownx snippets extension)."""
    return f"<!-- --8<-- [start:{name}] -->\n{text}\n<!-- --8<-- [end:{name}] -->"


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display), imported only when a plot is drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_grouped_bars(
    path: Path,
    groups: Sequence[str],
    stats: Mapping[str, Mapping[str, Mapping[str, Any]]],
    *,
    title: str,
    xlabel: str,
    value: str = "mean",
    spread: str | None = "std",
    ylim: tuple[float, float] | None = None,
) -> Path:
    """Figure-5-style bars: one group per entry of ``groups``, one bar per method, error bars = ``spread``.

    ``stats[method][group]`` is a ``summary`` dict; the group's count is printed under its label,
    as the paper prints the number of data points under each bar.
    """
    plt = pyplot()
    methods = [m for m in METHODS if m in stats]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * len(groups) + 1.5) + 2.2, 4.2), dpi=110)
    width = 0.8 / len(methods)
    x = np.arange(len(groups))
    for i, method in enumerate(methods):
        vals = [stats[method][g].get(value) for g in groups]
        errs = [stats[method][g].get(spread) if spread else None for g in groups]
        heights = [v if v is not None else np.nan for v in vals]
        yerr = [e if e is not None else 0.0 for e in errs] if spread else None
        ax.bar(
            x + (i - (len(methods) - 1) / 2) * width,
            heights,
            width,
            yerr=yerr,
            capsize=3,
            label=METHOD_LABELS.get(method, method),
            color=METHOD_COLOURS.get(method),
            error_kw={"elinewidth": 0.8, "alpha": 0.8},
        )
    if ylim is None:
        # Zoom on the bars' range as the paper's Figure 5 does (differences of a few points matter);
        # error bars of heavy-tailed methods may run off the axis rather than flatten every bar.
        lows = [v for m in methods for g in groups if (v := stats[m][g].get(value)) is not None]
        ylim = (5.0 * math.floor((min(lows, default=100.0) - 8.0) / 5.0), 102.0)
    counts = [stats[methods[0]][g].get("n", 0) for g in groups]
    ax.set_xticks(x, [f"{g}\n({n})" for g, n in zip(groups, counts)])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"accuracy {value} (%)" + (f" ± {spread}" if spread else ""))
    ax.set_title(title)
    ax.set_ylim(*ylim)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save(fig, path)


def plot_lines(
    path: Path,
    xs: Sequence[float],
    stats: Mapping[str, Sequence[Mapping[str, Any]]],
    *,
    title: str,
    xlabel: str,
) -> Path:
    """Accuracy against ``xs`` per method: mean (solid) and median (dashed).

    No std band: a heavy-tailed method's band would cover the whole plot; the spread is in the bars.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.4, 4.2), dpi=110)
    means = [s["mean"] for m in stats for s in stats[m] if s["mean"] is not None]
    ax.set_ylim(5.0 * math.floor((min(means, default=100.0) - 5.0) / 5.0), 101.0)
    for method in [m for m in METHODS if m in stats]:
        colour = METHOD_COLOURS.get(method)
        for key, style, suffix in (("mean", "o-", "mean"), ("median", "s--", "median")):
            ys = [s.get(key) if s.get(key) is not None else np.nan for s in stats[method]]
            ax.plot(xs, ys, style, color=colour, lw=1.8 if key == "mean" else 1.0, ms=5 if key == "mean" else 3,
                    label=f"{METHOD_LABELS.get(method, method)}, {suffix}")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("accuracy (%)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save(fig, path)


def plot_error_histograms(path: Path, errors_pct: Mapping[str, np.ndarray], *, title: str, limit: float | None = None) -> Path:
    """Histogram of signed relative errors per method; values beyond ±limit % land in the end bins.

    Without ``limit`` the range covers the 98th percentile of |error| of all methods (5 to 50 %).
    """
    plt = pyplot()
    methods = [m for m in METHODS if m in errors_pct]
    if limit is None:
        pooled = np.concatenate([np.asarray(errors_pct[m], dtype=np.float64) for m in methods])
        pooled = np.abs(pooled[np.isfinite(pooled)])
        limit = float(np.clip(np.ceil(np.percentile(pooled, 98)) if pooled.size else 5.0, 5.0, 50.0))
    fig, axes = plt.subplots(len(methods), 1, figsize=(6.4, 1.6 * len(methods) + 0.8), dpi=110, sharex=True)
    axes = np.atleast_1d(axes)
    bins = np.linspace(-limit, limit, 61)
    for ax, method in zip(axes, methods):
        e = np.asarray(errors_pct[method], dtype=np.float64)
        e = e[np.isfinite(e)]
        ax.hist(np.clip(e, -limit, limit), bins=bins, color=METHOD_COLOURS.get(method))
        beyond = int(np.sum(np.abs(e) >= limit))
        ax.set_ylabel("count")
        ax.text(
            0.01,
            0.8,
            f"{METHOD_LABELS.get(method, method)}: median {np.median(e):+.2f} %, |err| ≥ {limit:g} %: {beyond}"
            if e.size
            else f"{method}: no data",
            transform=ax.transAxes,
            fontsize=8,
            bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"},
        )
        ax.axvline(0.0, color="k", lw=0.6)
    axes[-1].set_xlabel("signed error 100 (m - g) / g (%)")
    return save(fig, path, title)
