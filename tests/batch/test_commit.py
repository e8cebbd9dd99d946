"""The commit of batch results: a driver killed (SIGKILL, real processes) at every phase boundary and
resumed gives every task exactly once, equal to an uninterrupted run; an unwritable --out or a full
disk is a one-line error that keeps what was done."""

from __future__ import annotations

import resource
import shutil
import signal
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from batch.faults import POINTS, STOP_ENV
from batch.results import paths
from batch_tables import depthruler, invoke, killed_after_first_part, stable, write_tasks

# Volatile columns of a row, and the run id: a resumed file mixes two runs.
DROP = {"run"}
BOUNDARIES = ["opened", "part-tmp:1", "part:1", "part:3", "merged", "sealed", "committed", "cleaning:1"]


@pytest.fixture(scope="module")
def table(archive, tmp_path_factory) -> tuple[Path, int]:
    """24 tasks on 8 frames (4 groups in one process) and 2 invalid rows (a fifth group): 26 tasks."""
    root = tmp_path_factory.mktemp("commit")
    bad = [[str(archive / "rec_poster"), 2**63, 1, 2, 3, 4, "", "huge frame"], [str(archive / "rec_poster"), 0, "", 2, 3, 4, "", "no pixel"]]
    path = write_tasks(root / "tasks.csv", archive, methods=("robust",), jitter=(0, 2, 4), extra_rows=bad)
    return path, 26


@pytest.fixture(scope="module")
def reference(table, tmp_path_factory) -> list[dict]:
    out = tmp_path_factory.mktemp("ref") / "ref.parquet"
    invoke(["batch", str(table[0]), "--out", str(out), "--workers", "1"])
    rows = stable(out, DROP)
    assert [r["task"] for r in rows] == list(range(table[1]))
    return rows


def test_the_boundaries_cover_every_stopping_point():
    assert sorted({b.partition(":")[0] for b in BOUNDARIES}, key=POINTS.index) == list(POINTS)


def _left(out: Path) -> dict[str, int]:
    """What lies beside ``out``: part files in the parts and merged folders, the temporary merge, the file."""
    parts, merged, tmp = paths(out)
    return {"parts": len(list(parts.glob("part-*.parquet"))) if parts.is_dir() else -1,
            "merged": len(list(merged.glob("part-*.parquet"))) if merged.is_dir() else -1,
            "tmp": int(tmp.is_file()), "out": int(out.is_file())}  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_killed_at_a_boundary_then_resumed_loses_and_repeats_nothing(table, reference, tmp_path, boundary):
    tasks_csv, n = table
    out = tmp_path / "r.parquet"
    args = ["batch", str(tasks_csv), "--out", str(out), "--workers", "1"]
    killed = depthruler(args, env={STOP_ENV: boundary})
    assert killed.returncode == -signal.SIGKILL, killed.stderr  # it reached the boundary and died there
    left = _left(out)
    if boundary in ("committed", "cleaning:1"):
        assert left["out"] == 1 and left["merged"] >= 0 and pq.read_table(out).num_rows == n  # merged, not cleaned up
    resumed = depthruler([*args, "--resume"])
    assert resumed.returncode == 0, resumed.stderr
    rows = stable(out, DROP)
    assert len(rows) == n and [r["task"] for r in rows] == list(range(n)), left  # every task exactly once
    assert rows == reference  # and each row as an uninterrupted run made it
    assert _left(out) == {"parts": -1, "merged": -1, "tmp": 0, "out": 1}
    assert "error rows by type: TaskError 2; by field: frame 1, p1_x 1" in resumed.stdout


@pytest.mark.slow
def test_a_resume_killed_again_and_a_pool_run_killed_between_parts(table, reference, tmp_path):
    tasks_csv, n = table
    out = tmp_path / "r.parquet"
    args = ["batch", str(tasks_csv), "--out", str(out)]
    assert depthruler([*args, "--workers", "2"], env={STOP_ENV: "part:2"}).returncode == -signal.SIGKILL
    assert _left(out)["parts"] == 2
    assert depthruler([*args, "--workers", "1", "--resume"], env={STOP_ENV: "sealed"}).returncode == -signal.SIGKILL
    assert _left(out) == {"parts": -1, "merged": 5, "tmp": 1, "out": 0}
    # the resumes that no kill stops run in this process (a process's start and imports cost seconds of CPU)
    assert f"{n} tasks, {n} already done; running 0" in invoke([*args, "--workers", "1", "--resume"])
    assert stable(out, DROP) == reference
    invoke([*args, "--workers", "1", "--resume"])  # a finished run resumed stays as it is
    assert stable(out, DROP) == reference


def _file_size_limit(limit: int):
    def set_limit() -> None:  # a write past the limit fails with EFBIG (Python ignores SIGXFSZ), as on a full disk
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return set_limit


def _one_line_error(proc) -> str:
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout
    return lines[0]


@pytest.mark.slow
def test_a_full_disk_is_a_one_line_error_that_keeps_what_was_done(table, reference, tmp_path):
    tasks_csv, n = table
    out = tmp_path / "r.parquet"
    args = ["batch", str(tasks_csv), "--out", str(out), "--workers", "1"]
    # the sizes of the parts and of the merge, from a run stopped when the merge is whole on disk
    assert depthruler(args, env={STOP_ENV: "merged"}).returncode == -signal.SIGKILL
    parts, merged, tmp = paths(out)
    part_sizes = sorted(p.stat().st_size for p in parts.glob("part-*.parquet"))
    merge_size = tmp.stat().st_size
    assert len(part_sizes) == 5 and part_sizes[-1] < merge_size
    shutil.rmtree(parts)  # start again from nothing
    tmp.unlink()

    # no room for a single part: nothing is written, the run says so in one line
    first = depthruler(args, preexec_fn=_file_size_limit(part_sizes[0] // 2))
    message = _one_line_error(first)
    assert "cannot write a result part" in message and "File too large" in message and "--resume" in message
    assert _left(out) == {"parts": 0, "merged": -1, "tmp": 0, "out": 0}
    # room for the parts but not for the merge: every part is kept
    second = depthruler([*args, "--resume"], preexec_fn=_file_size_limit((part_sizes[-1] + merge_size) // 2))
    message = _one_line_error(second)
    assert f"all {n} rows are kept in {parts}" in message and "--resume" in message
    assert _left(out) == {"parts": 5, "merged": -1, "tmp": 0, "out": 0}
    # with room again, the resume commits them, measuring nothing twice
    assert f"{n} tasks, {n} already done; running 0" in invoke([*args, "--resume"])  # in this process: no limit to set
    assert stable(out, DROP) == reference


@pytest.mark.slow
def test_an_unwritable_out_is_a_one_line_error_before_the_run(table, tmp_path):
    tasks_csv, _ = table
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    proc = depthruler(["batch", str(tasks_csv), "--out", str(blocker / "r.parquet"), "--workers", "1"])
    message = _one_line_error(proc)
    assert f"cannot write results beside {blocker / 'r.parquet'}" in message and "choose a writable --out" in message
    assert "measuring" not in proc.stdout  # refused before any task ran
    assert blocker.read_text() == "not a folder"
    # the same for a results path that is a folder
    folder = tmp_path / "r.parquet"
    folder.mkdir()
    message = _one_line_error(depthruler(["batch", str(tasks_csv), "--out", str(folder), "--workers", "1"]))
    assert "is a folder" in message


@pytest.mark.slow
def test_a_ray_data_run_killed_mid_run_resumes_to_every_task_once(table, reference, ray_address, tmp_path):
    """On Ray Data the workers write the parts: a driver joined to a running Ray (the session's, as
    on a cluster) and killed once parts are on disk; a driver on that Ray (this process, joined to it
    for the session: a process's start, imports and join cost seconds) resumes to the rows of a local
    run. (The commit's own kill points are the driver's whatever measured the parts: the pool's tests
    above kill them.)"""
    tasks_csv, n = table
    out = tmp_path / "r.parquet"
    args = ["batch", str(tasks_csv), "--out", str(out), "--ray", ray_address]
    parts = paths(out)[0]
    assert killed_after_first_part(args, parts) == -signal.SIGKILL, "the run ended before it could be killed"
    written = pq.read_table(parts).num_rows
    assert 0 < written < n and not out.exists()
    resumed = invoke([*args, "--resume"])
    assert "on Ray (2 CPUs on 1 node(s), 2 workers)" in resumed and f"{n} tasks, {written} already done; running {n - written}" in resumed, resumed
    rows = stable(out, DROP)
    assert [r["task"] for r in rows] == list(range(n)) and rows == reference
    assert _left(out) == {"parts": -1, "merged": -1, "tmp": 0, "out": 1}
