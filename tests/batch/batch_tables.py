"""Helpers of the batch tests: the CLI in-process, the simulated archive's truth, task tables, stable rows."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pyarrow.parquet as pq
from typer.testing import CliRunner

from cli.main import app as cli
from device.formats.recording import open_recording

ROOT = Path(__file__).resolve().parents[2]
SIZE = "width=480&height=270"
HEADER = ["source", "frame", "p1_x", "p1_y", "p2_x", "p2_y", "method", "label"]
# Columns that say where, when and how fast a row was made; everything else must match across executors.
VOLATILE = {"run", "worker", "finished", "frame_read_ms", "elapsed_ms"}


def invoke(args: list[str]) -> str:
    """The command's output, on one line (rich wraps long lines at the terminal width)."""
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output + repr(res.exception)
    return " ".join(res.output.split())


def truth(rec_dir: Path, i: int) -> dict:
    return open_recording(rec_dir).entries[i].meta["truth"]


def write_tasks(path: Path, archive: Path, methods=("robust", "paper", "basic"), jitter=(0, 2), extra_rows=()) -> Path:
    """Tasks on both recordings, their paths relative to the table's folder (as a table kept with its archive has them)."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(HEADER)
        for name in ("rec_poster", "rec_tilted"):
            rel = os.path.relpath(archive / name, path.parent)
            for i in range(4):
                t = truth(archive / name, i)
                (x1, y1), (x2, y2) = t["p1_px"], t["p2_px"]
                for m in methods:
                    for d in jitter:
                        w.writerow([rel, i, x1 + d, y1, x2 - d, y2, m, f"{name}/{i}/{t['length_m']}/{d}"])
        for row in extra_rows:
            w.writerow(row)
    return path


def stable(path: Path, drop: set[str] = frozenset()) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in VOLATILE | drop} for r in pq.read_table(path).to_pylist()]


def depthruler(args: list[str], env: dict[str, str] | None = None, preexec_fn=None) -> subprocess.CompletedProcess:
    """`depthruler ARGS` in a process of its own session; whatever it leaves running is killed when it
    ends (a pool's workers outlive a killed driver, and would hold pipes open: output goes to files)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]), **(env or {})}
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, "-m", "cli.main", *args], env=env, stdout=out, stderr=err,
                                text=True, start_new_session=True, preexec_fn=preexec_fn)  # fmt: skip
        try:
            proc.wait(timeout=300)
        finally:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(proc.args, proc.returncode, out.read(), err.read())


def killed_after_first_part(args: list[str], parts: Path, timeout: float = 300) -> int:
    """`depthruler ARGS` in a session of its own, killed with SIGKILL (its whole session: a pool's or a
    private Ray's processes too) once a first part is in ``parts``; its return code."""
    import time

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "cli.main", *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + timeout
        while not list(parts.glob("part-*.parquet")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    return proc.returncode
