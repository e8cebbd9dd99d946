"""Batch results on disk: streamed as Parquet parts while a run goes, one Parquet file at the end.

A Parquet file is readable only once its footer is written, so a run that streams into one file
loses everything in a crash. Instead each finished group is written as its own small Parquet file
``RESULTS.parquet.parts/part-NNNNNN.parquet`` (temporary name, fsync, rename: a part is whole or
absent); :meth:`ResultStore.finish` merges the parts (and, on ``--resume``, the rows of an earlier
complete file) into ``RESULTS.parquet`` and removes the parts. ``--resume`` reads the task keys
already in the parts (and the file) and runs only the others.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from batch.tasks import TaskError


class ResultsError(TaskError):
    """Results that cannot be written or read as asked; says what to change (--resume, --overwrite)."""


def _pa():
    import pyarrow as pa
    import pyarrow.parquet as pq

    return pa, pq


def read_table(path: Path):
    """A results file, or the parts of an unfinished one, as one pyarrow Table."""
    pa, pq = _pa()
    if path.is_dir():
        files = sorted(path.glob("part-*.parquet"))
        if not files:
            return pa.table({})
        return pa.concat_tables([pq.read_table(f) for f in files], promote_options="permissive")
    if not path.is_file():
        raise ResultsError(f"{path} does not exist; give a results file written by `depthruler batch --out`")
    try:
        return pq.read_table(path)
    except Exception as exc:  # noqa: BLE001 — pyarrow raises several types for a damaged file
        raise ResultsError(f"{path} is not a readable Parquet file ({exc})") from exc


class ResultStore:
    """Where one run's rows go. ``resume`` keeps earlier rows; ``overwrite`` discards them."""

    def __init__(self, out: Path, *, resume: bool = False, overwrite: bool = False) -> None:
        if out.suffix.lower() not in (".parquet", ".pq"):
            raise ResultsError(f"--out {out}: results are written as Parquet; name the file *.parquet")
        self.out = out
        self.parts = out.with_name(out.name + ".parts")
        if overwrite:
            shutil.rmtree(self.parts, ignore_errors=True)
            out.unlink(missing_ok=True)
        elif not resume and (out.exists() or self.parts.exists()):
            what = f"an interrupted run left {self.parts}" if self.parts.exists() else f"{out} exists"
            raise ResultsError(f"{what}; add --resume to finish that run or --overwrite to start again")
        out.parent.mkdir(parents=True, exist_ok=True)
        self.parts.mkdir(exist_ok=True)
        existing = sorted(self.parts.glob("part-*.parquet"))
        self._next = 1 + max((int(p.stem.split("-")[1]) for p in existing), default=0)
        for stale in self.parts.glob("*.tmp"):  # a part that was being written when the run died
            stale.unlink()

    def done(self) -> dict[int, str]:
        """task index -> task key of every row already written (parts and, on resume, the file)."""
        pa, pq = _pa()
        done: dict[int, str] = {}
        sources = [p for p in sorted(self.parts.glob("part-*.parquet"))] + ([self.out] if self.out.is_file() else [])
        for p in sources:
            t = pq.read_table(p, columns=["task", "task_key"])
            done.update(zip(t.column("task").to_pylist(), t.column("task_key").to_pylist()))
        return done

    def write(self, parquet: bytes) -> None:
        """Store one finished group (a whole Parquet file's bytes) durably as the next part."""
        path = self.parts / f"part-{self._next:06d}.parquet"
        self._next += 1
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            fh.write(parquet)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        fd = os.open(self.parts, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def finish(self, metadata: dict[str, str] | None = None) -> int:
        """Merge everything into ``out`` sorted by task (atomically) and remove the parts; row count."""
        pa, pq = _pa()
        tables = [read_table(self.parts)]
        if self.out.is_file():
            tables.insert(0, pq.read_table(self.out))
        tables = [t for t in tables if t.num_rows]
        table = pa.concat_tables(tables, promote_options="permissive") if tables else pa.table({"task": pa.array([], pa.int64())})
        if table.num_rows:
            table = table.sort_by([("task", "ascending")])
        if metadata:
            table = table.replace_schema_metadata({**(table.schema.metadata or {}), **{k.encode(): v.encode() for k, v in metadata.items()}})
        tmp = self.out.with_name(self.out.name + ".tmp")
        pq.write_table(table, tmp)
        os.replace(tmp, self.out)
        shutil.rmtree(self.parts, ignore_errors=True)
        return table.num_rows
