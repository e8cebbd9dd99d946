"""Result files merged into one Parquet file sorted by task, in bounded memory.

Holding every row of a run to sort it cost the driver ~1.8 kB a row (a million rows: ~1.8 GB).
:func:`merge_sorted` holds only the ``task`` column of all rows (8 B a row) and one output chunk:

1. read the ``task`` column of every row group of every input (a part is one row group; an
   earlier results file, written by this function, has one per chunk) and its smallest and
   largest task; refuse a task id that appears twice;
2. cut the sorted task ids into chunks of about :data:`CHUNK_BYTES` of rows (the size in memory
   of a row of the largest row group; Parquet's own sizes, of encoded pages, were 5x too small);
3. for each chunk, read the row groups whose task range meets the chunk's, keep their rows of the
   chunk, sort them by task and append them to the output as one row group, in the one schema
   that all inputs unify to (a column an input lacks is null there).

Tables whose groups hold neighbouring task ids (a table listed by recording and frame) read each
part about once; in the worst case (every part spanning the whole table) each part is read once
per chunk, more time but the same memory.
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import numpy as np

CHUNK_BYTES = 8 << 20  # rows of one output row group, by their size in memory (the merge holds ~3x this)


class DuplicateTasks(ValueError):
    """The inputs hold some task id more than once."""


def _conform(table, schema):  # noqa: ANN001, ANN202 — pyarrow Table and Schema
    import pyarrow as pa

    cols = []
    for f in schema:
        if f.name in table.column_names:
            col = table.column(f.name)
            cols.append(col if col.type == f.type else col.cast(f.type))
        else:
            cols.append(pa.nulls(table.num_rows, f.type))
    return pa.Table.from_arrays(cols, schema=schema)


def merge_sorted(sources: list[Path], out: BinaryIO, metadata: dict[str, str] | None = None, chunk_bytes: int = CHUNK_BYTES) -> int:
    """Write the rows of Parquet files ``sources`` to ``out`` sorted by ``task`` (module docstring);
    the number of rows. DuplicateTasks if a task id is in them twice (nothing useful written)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    units: list[tuple[Path, int, int, int]] = []  # file, row group, smallest task, largest task
    ids: list[np.ndarray] = []
    schemas = []
    rows = 0
    sample: tuple = (None, 0, 0)  # (file, row group, rows) of the largest row group, read once for the size of a row in memory
    for path in sources:
        pf = pq.ParquetFile(path)
        schemas.append(pf.schema_arrow)
        for rg in range(pf.num_row_groups):
            meta = pf.metadata.row_group(rg)
            if not meta.num_rows:
                continue
            task = pf.read_row_group(rg, columns=["task"]).column(0).to_numpy()
            ids.append(task)
            units.append((path, rg, int(task.min()), int(task.max())))
            rows += meta.num_rows
            if meta.num_rows > sample[2]:
                sample = (path, rg, meta.num_rows)
    schema = pa.unify_schemas(schemas, promote_options="permissive") if schemas else pa.schema([("task", pa.int64())])
    schema = schema.with_metadata({**(schema.metadata or {}), **{k.encode(): v.encode() for k, v in (metadata or {}).items()}})
    every = np.sort(np.concatenate(ids)) if ids else np.zeros(0, dtype=np.int64)
    if len(every) > 1 and bool(np.any(every[1:] == every[:-1])):
        raise DuplicateTasks(f"task {int(every[1:][every[1:] == every[:-1]][0])} is held twice")
    del ids
    per_row = pq.ParquetFile(sample[0]).read_row_group(sample[1]).nbytes / sample[2] if rows else 1.0
    step = max(1024, int(chunk_bytes / max(1.0, per_row)))
    with pq.ParquetWriter(out, schema) as writer:
        if not rows:
            writer.write_table(schema.empty_table())
        for start in range(0, len(every), step):
            lo, hi = int(every[start]), int(every[min(start + step, len(every)) - 1])
            pieces = []
            for path, rg, first, last in units:
                if last < lo or first > hi:
                    continue
                t = pq.ParquetFile(path).read_row_group(rg)
                task = t.column("task")
                pieces.append(_conform(t.filter(pc.and_(pc.greater_equal(task, lo), pc.less_equal(task, hi))), schema))
            chunk = pa.concat_tables(pieces).sort_by([("task", "ascending")])
            writer.write_table(chunk, row_group_size=max(1, chunk.num_rows))
    return rows
