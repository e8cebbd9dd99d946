"""`depthruler batch diff A B`: what changed between two batch results.

Rows pair up by what was measured — (source, frame or saved-frame uid, kind, clicked points), the
k-th such row of A with the k-th of B — so two runs with other options or another version of the
method compare. Each answer of a row is compared with its one-sigma (:data:`ANSWERS`): a segment's
distance, a height's, path's or area's value, each of a box's three dimensions. An answer *moved*
when ``|v_B - v_A|`` exceeds the larger of the two uncertainties (each answer lies outside the
other's +-u band); a row moved when any of its answers did, and is unchanged when all are equal.
Changes are summarised per kind (an area's in m², the others' in m). Verdicts compared: answered vs
error, the gap flag, and every column both files have among :data:`VERDICT_COLUMNS`.

Steps: read only the columns the comparison uses (a results row has ~50 columns, the diff needs
about 20), build one key per row with its occurrence number, join A and B on it with Arrow's hash
join and compare whole columns with numpy. Memory grows with the rows times those few columns, not
with Python objects per row. The options each run used (the file's ``depthruler.defaults``,
executor and version) are reported beside the counts.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from batch.results import column_names, read_metadata, read_table
from batch.schema import BOX_DIMENSIONS

MATCH = ("source", "frame", "frame_uid", "kind", "p1_x", "p1_y", "p2_x", "p2_y", "points", "on")
VERDICT_COLUMNS = ("quality", "gap_detected", "fit")
# (answer, its one-sigma) columns: a segment's, a height's / path's / area's, a box's three
ANSWERS = (("distance_m", "uncertainty_m"), ("value", "uncertainty"), *((f"{d}_m", f"{d}_sigma_m") for d in BOX_DIMENSIONS))
VALUES = ("task", "error", "kind", *(c for pair in ANSWERS for c in pair))
_KEY = "__key"


def _keyed(path: Path, columns: list[str]):
    """The ``columns`` of results ``path`` plus a key column: the MATCH values and their occurrence."""
    import pyarrow as pa
    import pyarrow.compute as pc

    t = read_table(path, columns=list(dict.fromkeys((*MATCH, *columns))))
    parts = [pc.fill_null(_as_text(t.column(c)), "\x00") if c in t.column_names else pa.nulls(t.num_rows, pa.string()).fill_null("\x00")
             for c in MATCH]  # fmt: skip
    key = pc.binary_join_element_wise(*parts, "\x1f") if t.num_rows else pa.array([], pa.string())
    key_np = np.asarray(key.to_numpy(zero_copy_only=False), dtype=object)
    _, inverse = np.unique(key_np, return_inverse=True) if len(key_np) else (None, np.zeros(0, int))
    order = np.argsort(inverse, kind="stable")
    first = np.r_[True, inverse[order][1:] != inverse[order][:-1]] if len(order) else np.zeros(0, bool)
    run_start = np.maximum.accumulate(np.where(first, np.arange(len(order)), 0)) if len(order) else order
    occurrence = np.empty(len(order), np.int64)
    occurrence[order] = np.arange(len(order)) - run_start
    full = pc.binary_join_element_wise(key, pa.array(occurrence.astype(str)), "\x1e") if t.num_rows else key
    keep = [c for c in (*MATCH[:2], *columns) if c in t.column_names]
    t = t.select(keep)
    for i, field in enumerate(t.schema):
        if pa.types.is_null(field.type):  # an all-null column of hand-made files: Arrow's join needs a type
            t = t.set_column(i, field.name, t.column(i).cast(pa.string()))
    return t.append_column(_KEY, full)


def _as_text(column):  # noqa: ANN001, ANN202 — a pyarrow ChunkedArray
    """``column`` as strings for the row key: a list column (a shape's clicks) as JSON text, by row."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if not pa.types.is_list(column.type) and not pa.types.is_large_list(column.type):
        return pc.cast(column, pa.string())
    return pa.array([None if v is None else json.dumps(v) for v in column.to_pylist()], pa.string())


def _float(table, name: str) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan)
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=float)


def _text(table, name: str) -> np.ndarray:
    return np.asarray(table.column(name).to_pylist(), dtype=object)


def _run_info(path: Path) -> dict[str, Any]:
    meta = read_metadata(path)
    try:
        options = json.loads(meta.get("depthruler.defaults", "{}"))
    except ValueError:
        options = {}
    return {"options": options, "version": meta.get("depthruler.version"), "executor": meta.get("depthruler.executor")}


def diff_results(a_path: Path, b_path: Path, top: int = 10) -> dict[str, Any]:
    """The summary of B against A (see the module docstring); ``top`` largest moves are listed."""
    names_a, names_b = column_names(a_path), column_names(b_path)
    columns = [c for c in VERDICT_COLUMNS if c in names_a and c in names_b]
    a = _keyed(a_path, [*VALUES, *columns])
    b = _keyed(b_path, [*VALUES, *columns])
    joined = a.join(b.select([_KEY, *[c for c in (*VALUES, *columns) if c in b.column_names]]), _KEY, join_type="inner",
                    left_suffix="_a", right_suffix="_b", use_threads=False)  # fmt: skip
    n = joined.num_rows

    def side(name: str, s: str) -> str:
        return f"{name}_{s}" if f"{name}_{s}" in joined.column_names else name

    err_a = np.array([bool(e) for e in joined.column(side("error", "a")).to_pylist()] if "error" in names_a else [False] * n, bool)
    err_b = np.array([bool(e) for e in joined.column(side("error", "b")).to_pylist()] if "error" in names_b else [False] * n, bool)
    status = Counter()
    for ea, eb in ((False, False), (False, True), (True, False), (True, True)):
        count = int(np.sum((err_a == ea) & (err_b == eb)))
        if count:
            status[("error" if ea else "answered") + " -> " + ("error" if eb else "answered")] = count
    both_ok = ~err_a & ~err_b
    verdicts: dict[str, dict[str, int]] = {}
    for c in columns:
        va, vb = _text(joined, side(c, "a")), _text(joined, side(c, "b"))
        changed = both_ok & (va != vb)
        if changed.any():
            verdicts[c] = dict(Counter(f"{x} -> {y}" for x, y in zip(va[changed], vb[changed])))
    kind_column = side("kind", "a")
    kind_a = _text(joined, kind_column) if kind_column in joined.column_names else np.full(n, None, object)
    kinds = np.where(np.equal(kind_a, None), "segment", kind_a).astype(str)  # files from before shapes: segments
    compared = np.zeros(n, bool)
    moved_row = np.zeros(n, bool)
    changed_row = np.zeros(n, bool)
    moves: list[tuple[float, int, str, float, float, float, float]] = []  # (|delta|, row, answer, a, b, u_a, u_b)
    abs_by_kind: dict[str, list[np.ndarray]] = {}
    for value, sigma in ANSWERS:
        va, vb = _float(joined, side(value, "a")), _float(joined, side(value, "b"))
        ua = np.nan_to_num(_float(joined, side(sigma, "a")), nan=0.0, posinf=0.0)
        ub = np.nan_to_num(_float(joined, side(sigma, "b")), nan=0.0, posinf=0.0)
        finite = np.isfinite(va) & np.isfinite(vb)
        delta = np.where(finite, vb - va, 0.0)
        moved = finite & (np.abs(delta) > np.maximum(ua, ub))
        compared |= finite
        moved_row |= moved
        changed_row |= finite & (delta != 0)
        for kind in np.unique(kinds[finite]):
            abs_by_kind.setdefault(str(kind), []).append(np.abs(delta[finite & (kinds == kind)]))
        biggest = np.flatnonzero(moved)
        biggest = biggest[np.argsort(-np.abs(delta[biggest]), kind="stable")][:top]
        moves += [(abs(float(delta[i])), int(i), value, float(va[i]), float(vb[i]), float(ua[i]), float(ub[i])) for i in biggest]
    moves.sort(key=lambda m: -m[0])  # stable: ties keep the ANSWERS order
    idx = np.array([m[1] for m in moves[:top]], dtype=np.int64)
    ta, tb = joined.column(side("task", "a")).take(idx).to_pylist(), joined.column(side("task", "b")).take(idx).to_pylist()
    src, frame = joined.column("source").take(idx).to_pylist(), joined.column("frame").take(idx).to_pylist()
    largest = [
        {"task_a": ta[j], "task_b": tb[j], "source": src[j], "frame": frame[j], "kind": str(kinds[i]), "answer": what,
         "a": a_v, "b": b_v, "delta": b_v - a_v, "uncertainty_a": u_a, "uncertainty_b": u_b}
        for j, (_, i, what, a_v, b_v, u_a, u_b) in enumerate(moves[:top])
    ]  # fmt: skip
    changes = {}
    for kind, parts in sorted(abs_by_kind.items()):
        d = np.sort(np.concatenate(parts))
        changes[kind] = {"unit": "m2" if kind == "area" else "m", "answers": len(d), "median_abs_change": float(d[len(d) // 2]), "max_abs_change": float(d[-1])}
    return {
        "a": str(a_path),
        "b": str(b_path),
        "runs": {"a": _run_info(a_path), "b": _run_info(b_path)},
        "rows_a": a.num_rows,
        "rows_b": b.num_rows,
        "matched": n,
        "only_in_a": a.num_rows - n,
        "only_in_b": b.num_rows - n,
        "status": dict(status),
        "compared": int(compared.sum()),
        "moved_beyond_uncertainty": int(moved_row.sum()),
        "unchanged_exactly": int(np.sum(compared & ~changed_row)),
        "changes_by_kind": changes,
        "verdict_changes": verdicts,
        "verdict_columns": columns,
        "largest_moves": largest,
    }
