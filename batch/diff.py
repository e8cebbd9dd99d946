"""`depthruler batch diff A B`: what changed between two batch results.

Rows pair up by what was measured — (source, frame or saved-frame uid, clicked points), the k-th such row of A with
the k-th of B — so two runs with other options or another version of the method compare. An answer
*moved* when ``|d_B - d_A|`` exceeds the larger of the two uncertainties (each answer lies outside
the other's +-u band). Verdicts compared: answered vs error, the gap flag, and every column both
files have among :data:`VERDICT_COLUMNS` (``quality`` once the method reports it).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

from batch.results import read_table

MATCH = ("source", "frame", "frame_uid", "p1_x", "p1_y", "p2_x", "p2_y")
VERDICT_COLUMNS = ("quality", "gap_detected", "fit")


def _keyed(rows: list[dict[str, Any]]) -> dict[tuple, dict[str, Any]]:
    seen: Counter = Counter()
    out = {}
    for r in rows:
        k = tuple(r.get(c) for c in MATCH)
        out[(*k, seen[k])] = r
        seen[k] += 1
    return out


def _num(x: Any) -> float | None:
    return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else None


def diff_results(a_path: Path, b_path: Path, top: int = 10) -> dict[str, Any]:
    """The summary of B against A (see the module docstring); ``top`` largest moves are listed."""
    a_table, b_table = read_table(a_path), read_table(b_path)
    a, b = _keyed(a_table.to_pylist()), _keyed(b_table.to_pylist())
    both = [k for k in a if k in b]
    status = Counter()
    moved: list[dict[str, Any]] = []
    deltas: list[float] = []
    verdicts: dict[str, Counter] = {}
    columns = [c for c in VERDICT_COLUMNS if c in a_table.column_names and c in b_table.column_names]
    for k in both:
        ra, rb = a[k], b[k]
        ok_a, ok_b = not ra.get("error"), not rb.get("error")
        status[("answered" if ok_a else "error") + " -> " + ("answered" if ok_b else "error")] += 1
        for c in columns:
            if ok_a and ok_b and ra.get(c) != rb.get(c):
                verdicts.setdefault(c, Counter())[f"{ra.get(c)} -> {rb.get(c)}"] += 1
        da, db = _num(ra.get("distance_m")), _num(rb.get("distance_m"))
        if da is None or db is None:
            continue
        delta = db - da
        deltas.append(delta)
        ua, ub = _num(ra.get("uncertainty_m")) or 0.0, _num(rb.get("uncertainty_m")) or 0.0
        if abs(delta) > max(ua, ub):
            moved.append(
                {"task_a": ra.get("task"), "task_b": rb.get("task"), "source": k[0], "frame": k[1],
                 "distance_a_m": da, "distance_b_m": db, "delta_m": delta, "uncertainty_a_m": ua, "uncertainty_b_m": ub}
            )  # fmt: skip
    moved.sort(key=lambda m: abs(m["delta_m"]), reverse=True)
    abs_d = sorted(abs(d) for d in deltas)
    return {
        "a": str(a_path),
        "b": str(b_path),
        "rows_a": len(a),
        "rows_b": len(b),
        "matched": len(both),
        "only_in_a": len(a) - len(both),
        "only_in_b": len(b) - len(both),
        "status": dict(status),
        "compared_distances": len(deltas),
        "moved_beyond_uncertainty": len(moved),
        "unchanged_exactly": sum(d == 0 for d in deltas),
        "median_abs_change_m": abs_d[len(abs_d) // 2] if abs_d else None,
        "max_abs_change_m": abs_d[-1] if abs_d else None,
        "verdict_changes": {c: dict(v) for c, v in verdicts.items()},
        "verdict_columns": columns,
        "largest_moves": moved[:top],
    }
