"""The check's per-pair table as CSV: one row per corner pair measured on one frame.

Columns: ``source`` (the spec checked), ``frame`` (index among the frames read), ``id1``, ``id2``
(chessboard corner ids), ``kind`` (row, column, diagonal), ``squares`` (the length in squares),
``true_mm``, ``measured_mm``, ``interval_lo_mm``, ``interval_hi_mm`` (the reported 95 % interval),
``error_pct`` (signed, % of the true length), ``accuracy`` (Eq. 8), ``quality``, ``covered`` (the
true length inside the interval), and the clicked corners ``p1_x``, ``p1_y``, ``p2_x``, ``p2_y``
(pixels). Written through :func:`history.csv_safe.writer`, so a source text that begins like a
formula is read as text; under a temporary name, renamed when whole.
"""

from __future__ import annotations

import os
from pathlib import Path

from history.csv_safe import writer

from check.pairs import PairResult

COLUMNS = ("source", "frame", "id1", "id2", "kind", "squares", "true_mm", "measured_mm", "interval_lo_mm", "interval_hi_mm",
           "error_pct", "accuracy", "quality", "covered", "p1_x", "p1_y", "p2_x", "p2_y")  # fmt: skip


def pair_row(source: str, p: PairResult) -> tuple:
    """One pair's cells, in :data:`COLUMNS` order."""
    return (source, p.frame, p.pair.id1, p.pair.id2, p.pair.kind, p.pair.squares, 1000 * p.pair.length_m, 1000 * p.measured_m,
            1000 * p.interval_m[0], 1000 * p.interval_m[1], p.error_pct, p.accuracy, p.quality, p.covered, *p.p1_px, *p.p2_px)  # fmt: skip


def write_pairs_csv(path: str | Path, source: str, pairs: tuple[PairResult, ...]) -> Path:
    """Write ``pairs`` of a check of ``source`` as the CSV file ``path``; the path."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = writer(fh)
        w.writerow(COLUMNS)
        w.writerows(pair_row(source, p) for p in pairs)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path
