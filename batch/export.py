"""A batch results file as CSV for spreadsheets (`depthruler batch export RESULTS.parquet --csv OUT.csv`).

Steps: read the Parquet file batch by batch (bounded memory); write one CSV row per result row,
the columns in the file's order; a list cell (end points, interval, warnings, reasons) as JSON
text, an empty cell for a missing value; every cell through :func:`history.csv_safe.writer`, so
text that begins like a formula (``=``, ``+``, ``-``, ``@``, tab, CR) is read as text. The
per-sample columns (``samples_px``, ``support``: hundreds of values per row, for drawing) are left
out unless asked for. The file is written under a temporary name and renamed when whole.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any

from history.csv_safe import writer

from batch.results import ResultsError

SAMPLE_COLUMNS = ("samples_px", "support")


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value


def export_csv(results: Path, out: Path, *, samples: bool = False, batch_rows: int = 4096) -> int:
    """Write results file ``results`` as the CSV file ``out`` (module docstring); the number of rows."""
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(results)
    except FileNotFoundError:
        raise ResultsError(f"{results} does not exist; give a results file written by `depthruler batch --out`") from None
    except Exception as exc:  # noqa: BLE001 — pyarrow raises several types for a damaged file
        raise ResultsError(f"{results} is not a readable Parquet file ({exc})") from None
    columns = [c for c in pf.schema_arrow.names if samples or c not in SAMPLE_COLUMNS]
    tmp = out.with_name(out.name + ".tmp")
    n = 0
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = writer(fh)
            w.writerow(columns)
            for batch in pf.iter_batches(batch_size=batch_rows, columns=columns):
                for row in batch.to_pylist():
                    w.writerow([_cell(row[c]) for c in columns])
                    n += 1
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, out)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise ResultsError(f"cannot write {out} ({exc.strerror or exc}); choose a writable --csv path with free space") from None
    return n
