"""Throughput of `depthruler batch`: tasks per second on 1 and 2 workers, process pool and Ray.

Run: ``.venv/bin/python bench/bench_batch.py`` or ``depthruler bench batch`` (``--write`` records the
table in bench/RESULTS.md; needs ``pip install 'depthruler[ray]'`` for the Ray rows, else they are
left out). The archive is made first: ``--recordings`` recordings of the simulated rig at 1280x720
(``--frames`` frames each, recorded with the recorder), and ``--clicks`` robust measurements per
frame. Every run is the whole batch through :func:`batch.run.run_batch` (read the frames,
measure, stream the Parquet parts, merge), timed from the first group submitted to the file
written, on workers that have already run one batch (process start-up and imports are reported
separately, not in the rate). The reference is the same batch in this process; runs of the
configurations being compared alternate, so all see the same load of this shared host.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import statistics
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from bench.results_file import machine, replace_section

SECTION = "## Batch re-measurement"
MEMORY_SECTION = "## Batch driver memory"


def make_archive(root: Path, recordings: int, frames: int, clicks: int) -> Path:
    """``recordings`` simulated recordings and a task table of ``clicks`` measurements per frame."""
    from device import open_source
    from device.formats.recording import RecordingWriter

    rows = []
    for r in range(recordings):
        spec = f"sim:poster?fps=0&distance={2.5 + r}&seed={r}&yaw={(-10, 10)[r % 2]}"
        out = root / f"rec{r}"
        with open_source(spec) as src, RecordingWriter(out, src.info) as w:
            for i in range(frames):
                f = src.read()
                w.write(f)
                t = f.meta["truth"]
                (x1, y1), (x2, y2) = t.p1_px, t.p2_px
                for k in range(clicks):  # clicks a few pixels apart along the target
                    rows.append([out.name, i, x1 + 2 * k, y1 + k % 3, x2 - 2 * k, y2 - k % 3])
    table = root / "tasks.csv"
    with table.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["source", "frame", "p1_x", "p1_y", "p2_x", "p2_y"])
        w.writerows(rows)
    return table


def noop_table(root: Path, n: int) -> Path:
    """A table of ``n`` no-op-cheap tasks: one small recording, every task on a frame it does not
    hold (4 tasks a frame), so each becomes an error row without a frame read or a measurement."""
    from device import open_source
    from device.formats.recording import RecordingWriter

    with open_source("sim:poster?fps=0&width=320&height=240") as src, RecordingWriter(root / "rec", src.info) as w:
        w.write(src.read())
    table = root / "noop.csv"
    with table.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["source", "frame", "p1_x", "p1_y", "p2_x", "p2_y"])
        w.writerows(("rec", 1 + k // 4, 10 + k % 4, 20, 300, 200) for k in range(n))
    return table


DRIVER = """
import json, resource, sys, time
from pathlib import Path
from batch.executors import RayExecutor
from batch.run import run_batch
from batch.tasks import TableFile

def hwm():
    return int(next(l for l in Path("/proc/self/status").read_text().splitlines() if l.startswith("VmHWM")).split()[1]) / 1024

stages = {}
ex = RayExecutor("local", num_cpus=2)
started = hwm()
t1 = time.perf_counter()
s = run_batch(TableFile.at(sys.argv[1]), Path(sys.argv[2]), ex, overwrite=True,
              on_start=lambda todo, done: stages.update(start_s=time.perf_counter() - t1, start_mb=hwm()))
ex.close()
print(json.dumps({"tasks": s["rows"], "rows": s["rows"], "groups": s["groups"], "ray_mb": started, "scan_s": stages["start_s"],
                  "scan_mb": stages["start_mb"], "run_s": time.perf_counter() - t1, "peak_mb": hwm()}))
"""


def driver_memory(n: int) -> dict:
    """The driver's peak RSS (VmHWM, MB) for ``n`` no-op-cheap tasks on a local Ray instance of 2
    CPUs, in a fresh interpreter: after reading the table, after starting Ray, at the end."""
    import json
    import subprocess
    import sys

    tmp = Path(tempfile.mkdtemp(prefix="bench_batch_mem_"))
    try:
        table = noop_table(tmp, n)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")])}
        out = subprocess.run([sys.executable, "-c", DRIVER, str(table), str(tmp / "out.parquet")], env=env, capture_output=True, text=True, check=False)
        if out.returncode:
            raise RuntimeError(out.stderr[-3000:])
        return json.loads(out.stdout.strip().splitlines()[-1])
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system) a local process has used so far, from /proc; None once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def ray_pids() -> set[int]:
    """The processes of the local Ray instance this process started (its raylet, GCS, agents and every
    worker: the ones that read, sort, measure, write and merge), found as descendants of this process
    whose command line names Ray."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except OSError:
                pass
    family, frontier = set(), {os.getpid()}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier} - family
        family |= frontier
    named = set()
    for p in family:
        try:
            if b"ray" in Path(f"/proc/{p}/cmdline").read_bytes():
                named.add(p)
        except OSError:
            pass
    return named


def timed_run(tasks, executor, out: Path, pids: set[int]) -> tuple[float, float, float, set[int]]:
    """One whole batch on ``executor``: (tasks per second, CPU seconds of this process and the
    measuring workers, CPU seconds of this process and every process of the executor, the measuring
    worker pids). ``pids``: the workers seen before, whose CPU is read before the run (a worker first
    seen in this run counts from its start). On Ray, every process of the local instance counts in
    the second figure (the raylet, GCS and the processes that read, sort, write and merge as well as
    those that measure); for a pool it is the first. On Ray the table's location is given, as the
    command line does: the workers read it (Ray Data)."""
    import pyarrow.parquet as pq

    from batch.executors import RayExecutor
    from batch.run import run_batch

    table, location = tasks
    on_ray = isinstance(executor, RayExecutor)
    family = ray_pids() if on_ray else set()
    before = {p: cpu_s(p) or 0.0 for p in pids | family | {os.getpid()}}
    t0 = time.perf_counter()
    s = run_batch(location if on_ray else table, out, executor, overwrite=True)
    wall = time.perf_counter() - t0
    assert s["rows"] == len(table)
    workers = {int(w.rsplit(":", 1)[1]) for w in pq.read_table(out, columns=["worker"]).column("worker").to_pylist()}
    after = {p: cpu_s(p) for p in workers | family | ray_pids() | {os.getpid()}} if on_ray else {p: cpu_s(p) for p in workers | {os.getpid()}}
    used = {p: (c or 0.0) - before.get(p, 0.0) for p, c in after.items() if c is not None}
    cpu = sum(used.get(p, 0.0) for p in workers | {os.getpid()})
    return len(table) / wall, cpu, sum(used.values()), workers


def run(recordings: int, frames: int, clicks: int, repeat: int) -> tuple[dict[str, dict], dict]:
    from batch.run import close_readers
    from batch.executors import InProcessExecutor, PoolExecutor, RayExecutor
    from batch.tasks import TableFile, read_tasks

    tmp = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    executors: dict = {}
    try:
        t0 = time.perf_counter()
        path = make_archive(tmp, recordings, frames, clicks)
        tasks = (read_tasks(path), TableFile.at(path))
        info = {"tasks": len(tasks[0]), "archive_s": time.perf_counter() - t0}
        out = tmp / "results.parquet"
        executors = {"in-process": InProcessExecutor(), "pool 1": PoolExecutor(1), "pool 2": PoolExecutor(2)}
        startup: dict[str, float] = {}
        try:
            import ray  # noqa: F401
        except ImportError:
            pass
        else:
            # One local Ray instance with 2 CPUs; "1 worker" = groups that reserve both CPUs, so one
            # runs at a time with the same Ray processes around it as for 2 workers.
            t1 = time.perf_counter()
            executors["ray 2"] = RayExecutor("local", num_cpus=2)
            info["ray_init_s"] = time.perf_counter() - t1
            executors["ray 1"] = RayExecutor("local", task_cpus=2)
        pids: dict[str, set[int]] = {}
        for name, ex in executors.items():  # start the workers: a first, untimed batch
            t1 = time.perf_counter()
            pids[name] = timed_run(tasks, ex, out, set())[3]
            startup[name] = time.perf_counter() - t1
        rates: dict[str, list[float]] = {k: [] for k in executors}
        cpus: dict[str, list[float]] = {k: [] for k in executors}
        cpus_all: dict[str, list[float]] = {k: [] for k in executors}
        for _ in range(repeat):  # alternate, so every configuration sees the same load of this shared host
            for name, ex in executors.items():
                rate, cpu, cpu_all, seen = timed_run(tasks, ex, out, pids[name])
                pids[name] |= seen
                rates[name].append(rate)
                cpus[name].append(cpu)
                cpus_all[name].append(cpu_all)
    finally:
        for ex in reversed(list(executors.values())):
            ex.close()
        close_readers()
        shutil.rmtree(tmp, ignore_errors=True)
    summary = {
        k: {
            "median": statistics.median(v),
            "best": max(v),
            "min": min(v),
            "startup_s": startup.get(k),
            "cpu_ms_per_task": 1e3 * statistics.median(cpus[k]) / info["tasks"],
            "all_cpu_ms_per_task": 1e3 * statistics.median(cpus_all[k]) / info["tasks"],
            # cores this run had on average: CPU seconds (of every process of the executor) over wall seconds
            "cores": statistics.median(c * r / info["tasks"] for c, r in zip(cpus_all[k], v)),
        }
        for k, v in rates.items()
    }
    return summary, info


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=4, help="simulated recordings in the archive (default 4)")
    ap.add_argument("--frames", type=int, default=6, help="frames per recording (default 6)")
    ap.add_argument("--clicks", type=int, default=6, help="measurements per frame (default 6)")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs per configuration (default 7)")
    ap.add_argument("--write", action="store_true", help=f"record the table in bench/RESULTS.md ({SECTION!r})")
    ap.add_argument("--memory", type=int, metavar="N", help="only measure the driver's peak memory for N no-op-cheap tasks on Ray")
    args = ap.parse_args(argv)
    if args.memory:
        started = datetime.now(timezone.utc)
        m = driver_memory(args.memory)
        text = "\n".join([
            MEMORY_SECTION, "",
            f"`bench/bench_batch.py --memory {args.memory}`: the driver (`run_batch` of the table's location on "
            "`RayExecutor('local', num_cpus=2)`: Ray Data, the workers read the table and write the parts; a fresh interpreter) over a "
            "table of no-op-cheap tasks (every task on a frame its small recording does not hold: an error row, no frame read). Peak "
            "RSS (VmHWM) of the driver process.", "",
            "| tasks | partitions | rows written | peak MB after starting Ray | after the scan | at the end (run + merge) | scan s | run s |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
            f"| {m['tasks']} | {m['groups']} | {m['rows']} | {m['ray_mb']:.0f} | {m['scan_mb']:.0f} | {m['peak_mb']:.0f} | {m['scan_s']:.1f} | {m['run_s']:.1f} |",
            "", f"Machine: {machine()}; {started:%Y-%m-%d %H:%M} UTC; load average {os.getloadavg()[0]:.2f} at the end.", "",
        ])  # fmt: skip
        print(text)
        if args.write:
            replace_section(MEMORY_SECTION, text)
        return
    if min(args.recordings, args.frames, args.clicks, args.repeat) < 1:
        ap.error("--recordings, --frames, --clicks and --repeat must be at least 1")
    load_before = os.getloadavg()
    started = datetime.now(timezone.utc)
    s, info = run(args.recordings, args.frames, args.clicks, args.repeat)
    load_after = os.getloadavg()
    ref = s["in-process"]["median"]

    def row(name: str, note: str = "") -> str:
        x = s[name]
        start = f"{x['startup_s']:.1f} s" if x["startup_s"] is not None else ""
        return (
            f"| {name} | {x['median']:.1f} | {x['best']:.1f} | {x['min']:.1f}-{x['best']:.1f} | {x['median'] / ref:.2f} | "
            f"{x['cpu_ms_per_task']:.1f} | {x['all_cpu_ms_per_task']:.1f} | {x['cores']:.2f} | {start} | {note} |"
        )

    def ratio(a: str, b: str, key: str) -> float:
        return s[a][key] / s[b][key]

    lines = [
        SECTION,
        "",
        f"`bench/bench_batch.py` (`depthruler bench batch --write`): {info['tasks']} tasks = {args.recordings} recordings of the "
        f"simulated rig (1280x720, {args.frames} frames each, made by the recorder) x {args.clicks} robust measurements per frame; "
        "one whole `run_batch` per run (read each frame once, measure, stream Parquet parts, merge), on workers that already ran "
        f"one batch; {args.repeat} runs per configuration, the configurations alternating run by run. Reference: the same batch "
        "in this process. Ray: Ray Data on one local instance with 2 CPUs, given the table's location as the command line does "
        "(a worker scans and reads it, Ray Data sorts the tasks, a Ray task per partition measures it and writes its part, in "
        "Ray's pooled worker processes, kept from run to run as a pool's are; every Ray run still pays its scan, sort, Ray Data's "
        "start and stop and the commit); its 1-worker row has tasks reserving both CPUs, one at a time. CPU: user + system time "
        "(/proc) of this process and the measuring worker processes; 'all processes' adds, on Ray, every other process of the "
        "Ray instance (raylet, GCS, agents, the processes that read, sort and merge); cores = all processes' CPU seconds per "
        "wall second, i.e. how much "
        "of the machine the run actually got.",
        "",
        "| executor | tasks/s median | best | range | median / in-process | CPU ms per task, measuring | all processes | cores used | first batch incl. start-up | note |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        row("in-process"),
        row("pool 1"),
        row("pool 2", f"{ratio('pool 2', 'pool 1', 'median'):.2f}x pool 1 (best {ratio('pool 2', 'pool 1', 'best'):.2f}x)"),
    ]
    summary_line = (
        f"2 workers over 1, median (best) runs: pool {ratio('pool 2', 'pool 1', 'median'):.2f}x "
        f"({ratio('pool 2', 'pool 1', 'best'):.2f}x)"
    )
    if "ray 1" in s:
        lines.append(row("ray 1", f"{ratio('ray 1', 'pool 1', 'median'):.2f}x pool 1"))
        lines.append(row("ray 2", f"{ratio('ray 2', 'ray 1', 'median'):.2f}x ray 1; {ratio('ray 2', 'pool 2', 'median'):.2f}x pool 2"))
        summary_line += (
            f", Ray {ratio('ray 2', 'ray 1', 'median'):.2f}x ({ratio('ray 2', 'ray 1', 'best'):.2f}x) (target >= 1.6x). "
            f"Ray's overhead over the pool in CPU per task of all processes: {100 * (ratio('ray 1', 'pool 1', 'all_cpu_ms_per_task') - 1):+.0f} % "
            f"at 1 worker, {100 * (ratio('ray 2', 'pool 2', 'all_cpu_ms_per_task') - 1):+.0f} % at 2 workers; in median rate: "
            f"{100 * (1 - ratio('ray 1', 'pool 1', 'median')):.0f} % at 1 worker, {100 * (1 - ratio('ray 2', 'pool 2', 'median')):.0f} % "
            f"at 2 workers. Starting Ray took {info['ray_init_s']:.1f} s."
        )
    else:
        summary_line += " (target >= 1.6x). Ray not installed: no Ray rows."
    summary_line += (
        f" On two idle cores the CPU per task would allow at most 2 x {s['pool 1']['cpu_ms_per_task']:.1f} / "
        f"{s['pool 2']['cpu_ms_per_task']:.1f} = {2 * ratio('pool 1', 'pool 2', 'cpu_ms_per_task'):.2f}x for the pool "
        "(an upper bound from CPU times, not a measured rate)."
    )
    lines += ["", summary_line]
    lines += [
        "",
        f"Machine: {machine()}; {started:%Y-%m-%d %H:%M} UTC; load average (1, 5, 15 min) "
        f"{', '.join(f'{v:.2f}' for v in load_before)} before, {', '.join(f'{v:.2f}' for v in load_after)} after.",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.write:
        replace_section(SECTION, text)
        print("written to bench/RESULTS.md")


if __name__ == "__main__":
    main()
