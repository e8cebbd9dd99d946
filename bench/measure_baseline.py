"""A reference revision of the measurement core, timed in a child process on the same calls as ours.

``Baseline(rev)`` extracts ``rev`` with `git archive` (the repository is left as it is) into a
temporary folder and starts ``bench/baseline_worker.py`` with that tree on its PYTHONPATH (``-P``: not
this tree). ``load`` hands it the frames and clicks, ``time`` times one of them there (CPU ms in the
child, one BLAS thread), so the bench can interleave both revisions call block by call block.
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
WORKER = Path(__file__).resolve().parent / "baseline_worker.py"


class Baseline:
    """The measurement core of revision ``rev`` in a child process (module docstring)."""

    def __init__(self, rev: str):
        self.rev = rev
        self.short = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], check=True, capture_output=True, text=True).stdout.strip()
        self.label = rev if rev == self.short else f"{rev} ({self.short})"
        self._tmp = tempfile.TemporaryDirectory(prefix="bench-measure-baseline-")
        tree = Path(self._tmp.name) / "tree"
        tree.mkdir()
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
        # One BLAS thread from the start: a BLAS library loaded after threadpool_limits (scipy's) would run multithreaded.
        env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        self._proc = subprocess.Popen([sys.executable, "-P", str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=tree, env=env)

    def _ask(self, req):
        pickle.dump(req, self._proc.stdin)
        self._proc.stdin.flush()
        return pickle.load(self._proc.stdout)

    def load(self, cases) -> None:
        """Hand over ``cases`` as (Frame, p1, p2); they are timed by index."""
        def fields(f):
            d = {k.name: getattr(f, k.name) for k in dataclasses.fields(f) if k.name != "meta"}
            return dict(d, camera=dataclasses.asdict(f.camera))
        self._ask(("load", [(fields(f), p1, p2) for f, p1, p2 in cases]))

    def time(self, i: int, method: str, repeats: int) -> tuple[np.ndarray, float]:
        """CPU and wall ms of ``repeats`` calls (rows) on case ``i`` and its distance (m; NaN on MeasureError)."""
        return self._ask(("time", i, method, repeats))

    def close(self) -> None:
        try:
            pickle.dump(("quit",), self._proc.stdin)
            self._proc.stdin.close()
            self._proc.wait(timeout=30)
        finally:
            self._tmp.cleanup()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
