"""Where the test suite's time goes, from the logs of ``pytest --durations=0`` runs: the generated note
``docs/test-times.md`` (docs/testing.md explains the folders and the fast loop it measures).

    python -m pytest --durations=0 -p no:cacheprovider > /tmp/full.txt
    python tests/durations.py --run today=/tmp/full.txt [--run before=/tmp/old.txt] --fast [--out docs/test-times.md] [--heavy]

``--heavy`` also rewrites ``tests/heavy.txt`` from the first run: the unit tests that cost the most,
which the fast loop leaves out (marker ``heavy``).

A test's time is the sum of its setup, call and teardown (a module- or session-scoped fixture is paid
in the setup of the first test that asks for it, as pytest reports it); its CPU seconds are those
``tests/cpu_times.py`` prints with ``--durations`` (the host is shared: CPU seconds move far less with
its load than wall seconds, and each run's load average is given). For each run the note gives the
totals, the share of the slowest 22 tests, the share of ``-m "not slow"`` and of the fast loop (both
selections collected here, on the current tree, matched by file basename and test id, so a run logged
before a file moved between folders still counts) and pytest's own session time; collection is timed
here with ``pytest --collect-only``. ``--fast`` runs the fast loop's command once here and writes its
wall and CPU seconds and the load beside it (``--fast-log LOG`` reads a log of that command instead).
Figures are this machine's on the date written.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DURATION = re.compile(r"^(\d+\.\d+)s (setup|call|teardown)\s+(\S.*)$")
CPU = re.compile(r"^(\d+\.\d+)s cpu (\S.*)$")  # tests/cpu_times.py's line per test
# ... and its closing line: the CPU of the whole run (with xdist's workers, once they have ended) and the load
RUN_LINE = re.compile(r"^run: .*, (\d+\.\d+)s cpu in this process and its ended children, load (\d+\.\d+)-(\d+\.\d+) ")
# ... and before it, the seconds the session spent building the measuring kernels before its first test
SESSION_START = re.compile(r"^session start: (\d+\.\d+)s wall, (\d+\.\d+)s cpu ")
BYTECODE = re.compile(r"; compiled files (written|not written)")  # ... which ends with whether Python wrote its compiled files
# the summary line, framed by "=" or, with -q (addopts), bare
SESSION = re.compile(r"^(?:=+ )?(.*) in (\d+\.\d+)s( \([\d:]+\))?(?: =+)?$")
COLLECTED = re.compile(r"(\d+)(?:/\d+)? tests? collected(?: \(\d+ deselected\))? in (\d+\.\d+)s")
# The fast loop of docs/testing.md: its selection, and the command that runs it on two workers (a
# worker takes a whole file, so a module's shared fixture is made once).
FAST_LOOP = ["-m", "not slow and not heavy and not integration and not study and not browser"]
FAST_LOOP_COMMAND = ["-n", "2", "--dist", "loadfile", *FAST_LOOP]
SLOWEST = 22
# A unit test is `heavy` (left out of the fast loop) when a full run measured it at this much CPU, or
# this much wall time for one that mostly waits (a server's answer, a subprocess).
HEAVY_FILE = ROOT / "tests" / "heavy.txt"
HEAVY_CPU_S = 0.5
HEAVY_WALL_S = 2.0
NOT_UNIT = ("tests/integration/", "tests/studies/", "tests/browser/")


@dataclass(frozen=True)
class Run:
    """One ``--durations=0`` log: per node id its wall seconds (setup + call + teardown) and CPU seconds,
    the final summary ("663 passed, ..."), pytest's session seconds, the whole run's CPU seconds
    (collection included), the load average's range, whether Python wrote its compiled files and the
    (wall, CPU) seconds spent building the measuring kernels before the first test (tests/session_start.py)."""

    wall: Counter
    cpu: Counter
    summary: str
    session: float | None
    run_cpu: float | None
    load: tuple[float, float] | None
    bytecode: str | None = None
    start: tuple[float, float] | None = None


def parse_log(text: str) -> Run:
    """The figures of a ``pytest --durations=0`` log (CPU and load only where tests/cpu_times.py ran)."""
    wall: Counter = Counter()
    cpu: Counter = Counter()
    summary, session, run_cpu, load, bytecode, start = "", None, None, None, None, None
    for line in text.splitlines():
        line = line.strip()
        if m := DURATION.match(line):
            wall[m.group(3).strip()] += float(m.group(1))
        elif m := CPU.match(line):
            cpu[m.group(2).strip()] += float(m.group(1))
        elif m := RUN_LINE.match(line):
            run_cpu, load = float(m.group(1)), (float(m.group(2)), float(m.group(3)))
            bytecode = b.group(1) if (b := BYTECODE.search(line)) else None
        elif m := SESSION_START.match(line):
            start = (float(m.group(1)), float(m.group(2)))
        elif (m := SESSION.match(line)) and ("passed" in m.group(1) or "failed" in m.group(1)):
            summary, session = m.group(1), float(m.group(2))
    return Run(wall, cpu, summary, session, run_cpu, load, bytecode, start)


def collect(*args: str) -> tuple[set[str], float]:
    """The node ids ``pytest --collect-only -q ARGS`` selects on this tree, and pytest's collection seconds."""
    # --verbosity=-1 whatever addopts says: one node id a line and the "collected in" line
    out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "--verbosity=-1", "-p", "no:cacheprovider", *args],
                         cwd=ROOT, capture_output=True, text=True, check=False).stdout
    ids = {line.strip() for line in out.splitlines() if "::" in line}
    m = COLLECTED.search(out)
    if not ids or not m:
        raise SystemExit(f"pytest --collect-only {' '.join(args)} collected nothing:\n{out[-2000:]}")
    return ids, float(m.group(2))


def key(node: str) -> str:
    """A node id without its folder: test basenames are unique, so a run logged before a test file
    moved between folders still matches today's selections."""
    path, _, rest = node.partition("::")
    return f"{Path(path).name}::{rest}"


def share(per_test: Counter, ids: set[str]) -> float:
    """Fraction of the run's test time spent in the tests ``ids`` names."""
    keys = {key(i) for i in ids}
    total = sum(per_test.values())
    return sum(s for node, s in per_test.items() if key(node) in keys) / total if total else 0.0


def top_share(per_test: Counter) -> float:
    total = sum(per_test.values())
    return sum(s for _, s in per_test.most_common(SLOWEST)) / total if total else 0.0


def run_fast_loop(log: Path) -> str:
    """Run the fast loop's command once here, its output into ``log``; returns the log's text."""
    cmd = [sys.executable, "-m", "pytest", *FAST_LOOP_COMMAND, "--durations=0", "-p", "no:cacheprovider"]
    with log.open("w") as out:
        subprocess.run(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, check=False)
    return log.read_text(errors="replace")


def fast_loop_lines(text: str) -> list[str]:
    """The note's paragraph on a log of the fast loop's command."""
    run = parse_log(text)
    load = f"{run.load[0]:.1f}-{run.load[1]:.1f}" if run.load else "not logged"
    command = " ".join(f'"{a}"' if " " in a else a for a in FAST_LOOP_COMMAND)
    starting = (f", and {run.start[1]:.1f} s building the measuring kernels or loading them from the caches before "
                "the workers started" if run.start else "")
    return [
        "## The fast loop",
        "",
        f"`.venv/bin/python -m pytest {command}`: {run.summary or 'no summary line'} in "
        f"{run.session if run.session is not None else 'n/a'} s wall on {os.cpu_count()} CPUs, "
        f"{sum(run.cpu.values()):.1f} s of CPU in its tests, {run.run_cpu if run.run_cpu is not None else 'n/a'} s in the "
        f"whole run (collection and the workers' start included{starting}); the host's 1-minute load average was {load} "
        "while it ran (other programs share the machine); compiled files were "
        f"{run.bytecode or 'not logged'} (when not, each worker compiles what no earlier run wrote: [Testing](testing.md)).",
        "",
        "| seconds | cpu | slowest in the fast loop |",
        "| --- | --- | --- |",
        *(f"| {s:.1f} | {run.cpu.get(node, 0.0):.1f} | `{node}` |" for node, s in run.wall.most_common(10)),
    ]


def report(runs: dict[str, str], fast_text: str | None = None) -> str:
    not_slow, _ = collect("-m", "not slow")
    fast, _ = collect(*FAST_LOOP)
    _, collect_s = collect()
    lines = [
        "# Test times",
        "",
        f"Generated by `python tests/durations.py` on {datetime.date.today()} ({platform.node() or 'this machine'}, "
        f"{os.cpu_count()} CPUs, Python {platform.python_version()}); do not edit by hand. How the suite is laid "
        "out and which command is the fast loop: [Testing](testing.md).",
        "",
        f"Collecting the whole suite on today's tree: {collect_s:.1f} s. Shares are of the summed test time "
        f"(setup + call + teardown), in wall seconds and in CPU seconds; the selections are collected on "
        f"today's tree ({len(not_slow)} tests `-m \"not slow\"`, {len(fast)} in the fast loop).",
        "",
        "| run | result | session (s) | load | summed tests (s) | CPU (s) | slowest 22 | slowest 22, CPU | "
        "`-m \"not slow\"` | fast loop |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    slowest_tables, starts = [], []
    for label, path in runs.items():
        run = parse_log(Path(path).read_text(errors="replace"))
        total = sum(run.wall.values())
        load = f"{run.load[0]:.1f}-{run.load[1]:.1f}" if run.load else "n/a"
        cpu = f"{sum(run.cpu.values()):.1f}" if run.cpu else "n/a"
        cpu_top = f"{top_share(run.cpu):.1%}" if run.cpu else "n/a"
        lines.append(f"| {label} | {run.summary or f'{len(run.wall)} tests timed'} | {run.session if run.session is not None else 'n/a'} | "
                     f"{load} | {total:.1f} | {cpu} | {top_share(run.wall):.1%} | {cpu_top} | {share(run.wall, not_slow):.1%} | "
                     f"{share(run.wall, fast):.1%} |")
        starts.append(f"Before its first test, run {label} spent "
                      + (f"{run.start[0]:.1f} s wall ({run.start[1]:.1f} s CPU) building the measuring kernels or loading them "
                         "from the caches (tests/session_start.py): in no test's time nor in pytest's session seconds, so "
                         "not in the shares above."
                         if run.start else "nothing logged compiling the measuring kernels (an older log: the first test that "
                         "measured carried it)."))
        slowest_tables += ["", f"## Slowest {SLOWEST}: {label}", "", "| seconds | cpu | test |", "| --- | --- | --- |"]
        slowest_tables += [f"| {s:.1f} | {run.cpu[node]:.1f} | `{node}` |" if run.cpu else f"| {s:.1f} | n/a | `{node}` |"
                           for node, s in run.wall.most_common(SLOWEST)]
    if fast_text is not None:
        slowest_tables = ["", *fast_loop_lines(fast_text), *slowest_tables]
    first = parse_log(Path(next(iter(runs.values()))).read_text(errors="replace"))
    return "\n".join(lines + ["", *starts] + slowest_tables + what_moves_the_share(first.wall)) + "\n"


def folder(node: str) -> str:
    """The folder of a test's file: ``tests/sim/`` for ``tests/sim/test_box.py::test_x``."""
    return node.split("::")[0].rsplit("/", 1)[0] + "/"


def scaled(per_test: Counter, picked: Callable[[str], bool], factor: float) -> Counter:
    """``per_test`` with the tests ``picked`` taking ``factor`` of their time."""
    return Counter({node: s * (factor if picked(node) else 1.0) for node, s in per_test.items()})


def what_moves_the_share(per_test: Counter) -> list[str]:
    """The slowest-22 share if a folder's tests (or several folders', or only the slowest 22) took half
    their time (the slowest 22 also three quarters): a model on the run's own times, not a run."""
    time_in: Counter = Counter()
    for node, s in per_test.items():
        time_in[folder(node)] += s
    heaviest = [f for f, _ in time_in.most_common(5)]
    top = {node for node, _ in per_test.most_common(SLOWEST)}
    rows = [("as run", top_share(per_test))]
    rows += [(f"`{f}` at half its time", top_share(scaled(per_test, lambda n, f=f: folder(n) == f, 0.5))) for f in heaviest]
    rows.append((f"those {len(heaviest)} folders at half", top_share(scaled(per_test, lambda n: folder(n) in heaviest, 0.5))))
    rows.append(("every test at half", top_share(scaled(per_test, lambda n: True, 0.5))))
    rows += [(f"only the slowest {SLOWEST} at {name}", top_share(scaled(per_test, top.__contains__, f))) for name, f in (("three quarters", 0.75), ("half", 0.5))]
    return ["", f"## What moves the slowest-{SLOWEST} share", "",
            f"A model on the first run's wall times, not a run: the share of the slowest {SLOWEST} (ranked again) if the "
            "tests of the folders that take the most time took half of it. A share is a ratio: a speed-up of the suite's "
            "bulk leaves it where it is, and only the slowest tests gaining on the rest move it.", "",
            "| if | slowest 22 |", "| --- | --- |", *(f"| {label} | {v:.1%} |" for label, v in rows)]


def heavy_tests(run: Run) -> list[str]:
    """The unit tests of a full run's log that cost at least ``HEAVY_CPU_S`` of CPU or ``HEAVY_WALL_S``
    of wall time (setup, call and teardown), sorted by node id."""
    return sorted(node for node in run.wall.keys() | run.cpu.keys()
                  if not node.startswith(NOT_UNIT)
                  and (run.cpu[node] >= HEAVY_CPU_S or run.wall[node] >= HEAVY_WALL_S))


def heavy_text(nodes: list[str], label: str) -> str:
    """``tests/heavy.txt``: a header naming the run it was measured on, then one node id per line."""
    return (f"# Generated by `python tests/durations.py --run {label}=LOG --heavy`; do not edit by hand.\n"
            f"# Unit tests at >= {HEAVY_CPU_S} s CPU or >= {HEAVY_WALL_S} s wall in that full run: marked `heavy`\n"
            "# by tests/conftest.py, left out of the fast loop, run by the full suite.\n"
            + "".join(f"{node}\n" for node in nodes))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", action="append", required=True, metavar="LABEL=LOG",
                        help="a label and the log of a `pytest -q --durations=0` run; repeat to compare runs")
    parser.add_argument("--fast", action="store_true", help="run the fast loop's command once here and give its times")
    parser.add_argument("--fast-log", type=Path, metavar="LOG", help="a log of the fast loop's command with --durations=0, instead of --fast")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "test-times.md")
    parser.add_argument("--heavy", action="store_true",
                        help=f"also write {HEAVY_FILE.relative_to(ROOT)} from the first run (a full run's log)")
    args = parser.parse_args()
    runs = dict(r.split("=", 1) for r in args.run)
    if args.heavy:
        label, log = next(iter(runs.items()))
        HEAVY_FILE.write_text(heavy_text(heavy_tests(parse_log(Path(log).read_text(errors="replace"))), label))
        print(HEAVY_FILE)
    fast_text = None
    if args.fast_log is not None:
        fast_text = args.fast_log.read_text(errors="replace")
    elif args.fast:
        with tempfile.TemporaryDirectory() as tmp:
            fast_text = run_fast_loop(Path(tmp) / "fast.txt")
    args.out.write_text(report(runs, fast_text))
    print(args.out)


if __name__ == "__main__":
    main()
