"""Batch results on disk: Parquet parts while a run goes, one Parquet file committed at the end.

Beside ``RESULTS.parquet`` a run keeps

- ``RESULTS.parquet.parts/part-NNNNNN.parquet``: one file per finished group, written under a
  ``.tmp`` name, fsync'd and renamed, so a part is whole or absent;
- ``RESULTS.parquet.tmp``: the merge being written;
- ``RESULTS.parquet.merged/``: the parts folder, renamed once the merge is whole on disk.

:meth:`ResultStore.finish` commits in four steps: (1) merge the rows of an earlier results file
(``--resume``) and the parts into ``.tmp``, sorted by task in bounded memory (:mod:`batch.merge`),
and fsync it; (2) rename ``.parts`` to ``.merged``, the commit point; (3) rename ``.tmp`` onto
``RESULTS.parquet``; (4) remove ``.merged``. :func:`recover`, run when a store opens, reads the state a killed process left: before
step 2 the ``.tmp`` is discarded and the parts stay to be merged again; from step 2 on the merge is
the truth and steps 3-4 are completed. Every task's row is then in exactly one of the results file
and the parts, so ``--resume`` neither repeats nor drops a task; a merge that would hold a task id
twice is refused. Every write error is a :class:`ResultsError` that says what was kept.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from batch.faults import reached
from batch.tasks import TaskError


class ResultsError(TaskError):
    """Results that cannot be written or read as asked; says what to change (--resume, --overwrite)."""


def _pa():
    import pyarrow as pa
    import pyarrow.parquet as pq

    return pa, pq


def read_table(path: Path, columns: list[str] | None = None):
    """A results file, or the parts of an unfinished one, as one pyarrow Table; ``columns`` (those
    the file has among them) reads only those."""
    pa, pq = _pa()
    if path.is_dir():
        files = sorted(path.glob("part-*.parquet"))
        if not files:
            return pa.table({})
        tables = [pq.read_table(f, columns=_present(pq.read_schema(f).names, columns)) for f in files]
        return pa.concat_tables(tables, promote_options="permissive")
    if not path.is_file():
        raise ResultsError(f"{path} does not exist; give a results file written by `depthruler batch --out`")
    try:
        return pq.read_table(path, columns=_present(pq.read_schema(path).names, columns))
    except Exception as exc:  # noqa: BLE001 — pyarrow raises several types for a damaged file
        raise ResultsError(f"{path} is not a readable Parquet file ({exc})") from exc


def _present(names: list[str], columns: list[str] | None) -> list[str] | None:
    return None if columns is None else [c for c in columns if c in names] or names[:0]


def column_names(path: Path) -> set[str]:
    """The column names of a results file or of any part of an unfinished one."""
    _, pq = _pa()
    if not path.exists():
        raise ResultsError(f"{path} does not exist; give a results file written by `depthruler batch --out`")
    files = sorted(path.glob("part-*.parquet")) if path.is_dir() else [path]
    try:
        return {name for f in files for name in pq.read_schema(f).names}
    except Exception as exc:  # noqa: BLE001
        raise ResultsError(f"{path} is not a readable Parquet file ({exc})") from exc


def read_metadata(path: Path) -> dict[str, str]:
    """The key/value metadata of a committed results file (empty for a parts folder)."""
    _, pq = _pa()
    if path.is_dir():
        return {}
    try:
        meta = pq.read_schema(path).metadata or {}
    except Exception as exc:  # noqa: BLE001
        raise ResultsError(f"{path} is not a readable Parquet file ({exc})") from exc
    return {k.decode(): v.decode() for k, v in meta.items() if not k.startswith(b"ARROW:")}


def paths(out: Path) -> tuple[Path, Path, Path]:
    """The parts folder, the merged-parts folder and the temporary merge of results file ``out``."""
    return out.with_name(out.name + ".parts"), out.with_name(out.name + ".merged"), out.with_name(out.name + ".tmp")


def _sync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove_tree(folder: Path) -> None:
    """Remove ``folder`` file by file (the ``cleaning`` stopping point lies between two files)."""
    for n, f in enumerate(sorted(folder.iterdir()), 1):
        f.unlink()
        reached("cleaning", n)
    folder.rmdir()


def recover(out: Path) -> None:
    """Finish or undo what a process killed during :meth:`ResultStore.finish` left (module docstring)."""
    parts, merged, tmp = paths(out)
    if merged.is_dir():
        if tmp.is_file():
            os.replace(tmp, out)
        elif not out.is_file():  # the merge is gone (deleted by hand): its parts are the only copy
            os.replace(merged, parts)
            _sync_dir(out.parent)
            return
        _sync_dir(out.parent)
        _remove_tree(merged)
    else:
        tmp.unlink(missing_ok=True)


def leftovers(out: Path) -> list[Path]:
    """What an earlier run left beside ``out``: the file itself and any of its parts or merges."""
    return [p for p in (out, *paths(out)) if p.exists()]


def write_part(path: Path, parquet: bytes, n: int = 1) -> None:
    """Write one part durably: under a ``.tmp`` name, fsync'd, renamed onto ``path``, the folder fsync'd
    (the ``part-tmp`` stopping point, the ``n``-th, lies before the rename). OSError as raised, the
    temporary file removed."""
    tmp = path.with_suffix(".tmp")
    try:
        with open(tmp, "wb") as fh:
            fh.write(parquet)
            fh.flush()
            os.fsync(fh.fileno())
        reached("part-tmp", n)
        os.replace(tmp, path)
        _sync_dir(path.parent)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise


def merge_file(tmp: Path, sources: list[Path], metadata: dict[str, str] | None) -> int:
    """Merge the rows of ``sources`` into the file ``tmp`` sorted by task (:func:`batch.merge.merge_sorted`),
    fsync'd; its row count. DuplicateTasks or OSError as raised."""
    from batch.merge import merge_sorted

    with open(tmp, "wb") as fh:
        rows = merge_sorted(sources, fh, metadata)
        fh.flush()
        os.fsync(fh.fileno())
    return rows


def done_tasks(out: Path):  # noqa: ANN201 — two numpy arrays
    """(task indices, task keys) of every row of results file ``out`` and of its parts, as two numpy
    arrays (a dict of a million tasks would cost ~150 MB)."""
    import numpy as np

    _, pq = _pa()
    ids, keys = [], []
    parts = paths(out)[0]
    sources = sorted(parts.glob("part-*.parquet")) + ([out] if out.is_file() else [])
    for p in sources:
        try:
            t = pq.read_table(p, columns=["task", "task_key"])
        except Exception as exc:  # noqa: BLE001 — pyarrow raises several types for a damaged file
            raise ResultsError(f"{p} is not a results file of depthruler batch ({exc}); use --overwrite to start again") from None
        ids.append(t.column("task").to_numpy())
        keys.append(np.asarray(t.column("task_key").to_pylist(), dtype=object))
    if not ids:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=object)
    return np.concatenate(ids).astype(np.int64), np.concatenate(keys)


class ResultStore:
    """Where one run's rows go. ``resume`` keeps earlier rows; ``overwrite`` discards them."""

    def __init__(self, out: Path, *, resume: bool = False, overwrite: bool = False) -> None:
        if out.suffix.lower() not in (".parquet", ".pq"):
            raise ResultsError(f"--out {out}: results are written as Parquet; name the file *.parquet")
        if out.is_dir():
            raise ResultsError(f"--out {out} is a folder; name a *.parquet file to write")
        self.out = out
        self.parts, self.merged, self.tmp = paths(out)
        try:
            if overwrite:
                shutil.rmtree(self.parts, ignore_errors=True)
                shutil.rmtree(self.merged, ignore_errors=True)
                self.tmp.unlink(missing_ok=True)
                out.unlink(missing_ok=True)
            elif not resume and leftovers(out):
                what = f"{out} exists" if out.exists() else f"an interrupted run left {leftovers(out)[0]}"
                raise ResultsError(f"{what}; add --resume to finish that run or --overwrite to start again")
            out.parent.mkdir(parents=True, exist_ok=True)
            recover(out)
            self.parts.mkdir(exist_ok=True)
            for stale in self.parts.glob("*.tmp"):  # a part that was being written when the run died
                stale.unlink()
            probe = self.parts / ".probe.tmp"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise ResultsError(f"cannot write results beside {out} ({exc.strerror or exc}); choose a writable --out") from None
        numbered = [p.stem.split("-")[1] for p in self.parts.glob("part-*.parquet")]  # a Ray worker's parts are named by their first task
        self._next = 1 + max((int(n) for n in numbered if n.isdigit()), default=0)
        self._written = 0
        reached("opened")

    def done(self):  # noqa: ANN201 — two numpy arrays
        """(task indices, task keys) of every row already written (parts and, on resume, the file),
        as two numpy arrays (:func:`done_tasks`)."""
        return done_tasks(self.out)

    def write(self, parquet: bytes) -> None:
        """Store one finished group (a whole Parquet file's bytes) durably as the next part."""
        try:
            write_part(self.parts / f"part-{self._next:06d}.parquet", parquet, self._written + 1)
        except OSError as exc:
            raise ResultsError(
                f"cannot write a result part in {self.parts} ({exc.strerror or exc}); the {self._written} group(s) written "
                "are kept: free space or fix the folder, then run again with --resume"
            ) from None
        self._next += 1
        self._written += 1
        reached("part", self._written)

    def finish(self, metadata: dict[str, str] | None = None, merge: Callable[[Path, list[Path], dict[str, str] | None], int] | None = None) -> int:
        """Commit everything to ``out`` sorted by task (module docstring) and return its row count.
        ``merge`` does step 1 (:func:`merge_file` here; on Ray the same function in a Ray task, so
        the rows never pass through the driver) and raises what it raises."""
        from batch.merge import DuplicateTasks

        _, pq = _pa()
        parts = sorted(self.parts.glob("part-*.parquet"))
        if not parts and self.out.is_file():  # nothing new: the file is already the whole run
            shutil.rmtree(self.parts, ignore_errors=True)
            return pq.ParquetFile(self.out).metadata.num_rows
        sources = ([self.out] if self.out.is_file() else []) + parts
        try:
            rows = (merge or merge_file)(self.tmp, sources, metadata)
        except DuplicateTasks as exc:
            self.tmp.unlink(missing_ok=True)
            raise ResultsError(f"the rows of {self.out} and {self.parts} hold a task twice ({exc}); nothing was merged: use --overwrite") from None
        except OSError as exc:
            with contextlib.suppress(OSError):
                self.tmp.unlink(missing_ok=True)
            raise ResultsError(
                f"cannot write {self.tmp} ({exc.strerror or exc}); all {sum(pq.ParquetFile(p).metadata.num_rows for p in sources)} "
                f"rows are kept in {self.parts}"
                + (f" and {self.out}" if self.out.is_file() else "")
                + ": free space (the merge needs about their size again), then run again with --resume"
            ) from None
        reached("merged")
        os.replace(self.parts, self.merged)
        _sync_dir(self.out.parent)
        reached("sealed")
        os.replace(self.tmp, self.out)
        _sync_dir(self.out.parent)
        reached("committed")
        _remove_tree(self.merged)
        return rows
