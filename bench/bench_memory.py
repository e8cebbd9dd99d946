"""Where an idle service's resident memory goes: the process built up stage by stage, and the
idle server's mappings.

Each stage is a fresh interpreter that does everything up to that stage, with the server's
allocator settings (``service.connections.return_large_blocks``), and reports its resident set
(VmRSS, split into file-backed pages and anonymous memory, from /proc): the scientific base
(numpy, scipy.special, OpenCV), numba imported, numba's runtime started (what the first compiled
kernel's load does: LLVM's start and its runtime module compiled), the measuring kernels loaded
and warmed up (``measure.warm_up``), the service's modules, and the default simulator open with
three frames read one after another, as the capture thread reads them. Then `depthruler serve` at its defaults (the simulator) is left idle until its
ring is full, and its mappings are grouped: LLVM's library (``libllvmlite.so``), the other mapped
files, the heap and anonymous mappings. Figures go to bench/RESULTS.md "## Service memory".

    python bench/bench_memory.py [--settle 60] [--write]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from bench.bench_service_load import idle_default_server
from bench.results_file import machine, replace_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Service memory"

# (label, code run after the previous stages' code), cumulative
STAGES = [
    ("Python, numpy, scipy.special, OpenCV", "import numpy, scipy.special, cv2"),
    ("+ numba imported", "import numba"),
    ("+ numba's runtime started (LLVM, its runtime module compiled)",
     "from numba.core.registry import cpu_target; cpu_target.target_context.refresh()"),
    ("+ the measuring kernels loaded and warmed up", "import measure; measure.warm_up()"),
    ("+ the service's modules", "import service.app"),
    ("+ the default simulator open, 3 frames read one after another (the last one kept)",
     "from device import open_source; src = open_source('sim?fps=0'); src.open()\nfor _ in range(3): frame = src.read()"),
]
STATUS = ("VmRSS", "RssAnon", "RssFile")


def _status_mb(pid: int | str = "self") -> dict[str, float]:
    out = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key = line.split(":", 1)[0]
        if key in STATUS:
            out[key] = int(line.split()[1]) / 1024
    return out


def stage(k: int) -> dict[str, float]:
    """RSS (MB) of a fresh interpreter that ran stages 0..k."""
    code = "\n".join(
        ["import json, sys", "from service.connections import return_large_blocks", "return_large_blocks()"]
        + [c for _, c in STAGES[: k + 1]]
        + ["from bench.bench_memory import _status_mb", "print(json.dumps(_status_mb()))"]
    )
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def mappings_mb(pid: int) -> dict[str, float]:
    """The resident pages of ``pid`` by mapping: LLVM's library, other files, the heap, anonymous."""
    groups: Counter = Counter()
    name = "anonymous"
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            parts = line.split(maxsplit=5)
            path = parts[5].strip() if len(parts) > 5 else ""
            if "libllvmlite" in path:
                name = "libllvmlite.so (LLVM)"
            elif path == "[heap]":
                name = "heap"
            elif path.startswith("/") and not path.startswith("/dev/zero"):
                name = "other mapped files"
            else:
                name = "anonymous"
        elif line.startswith("Rss:"):
            groups[name] += int(line.split()[1]) / 1024
    return dict(groups)


def idle_server(settle_s: float) -> dict:
    """`depthruler serve` at its defaults left idle until its ring stops growing: RSS and mappings."""
    with tempfile.TemporaryDirectory() as tmp, idle_default_server(ROOT, Path(tmp), settle_s) as (proc, health):
        return {"rss": _status_mb(proc.pid), "mappings": mappings_mb(proc.pid), "ring_mb": health["ring_bytes"] / 1e6}


def report(stages: list[dict[str, float]], idle: dict, head: str) -> str:
    rows, prev = [], 0.0
    for (label, _), s in zip(STAGES, stages):
        rows.append(f"| {label} | {s['VmRSS']:.0f} | {s['VmRSS'] - prev:+.0f} | {s['RssFile']:.0f} | {s['RssAnon']:.0f} |\n")
        prev = s["VmRSS"]
    maps = "".join(f"| {k} | {v:.0f} |\n" for k, v in sorted(idle["mappings"].items(), key=lambda kv: -kv[1]))
    return (
        f"{SECTION}\n\n`bench/bench_memory.py` (`depthruler bench memory --write`) on {head}: a process built up stage by stage "
        "(a fresh interpreter per row, with the server's allocator settings), resident memory in MB "
        "(VmRSS, of it file-backed pages and anonymous memory).\n\n"
        "| stage | RSS | step | file | anonymous |\n| --- | --- | --- | --- | --- |\n" + "".join(rows)
        + f"\n`depthruler serve` at its defaults (the simulator), idle until its ring is full: RSS {idle['rss']['VmRSS']:.0f} MB "
        f"(ring {idle['ring_mb']:.0f} MB by /api/health), its resident pages by mapping (MB):\n\n"
        "| mapping | MB |\n| --- | --- |\n" + maps
        + f"\nMachine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settle", type=float, default=60.0, help="seconds at most for the idle server's ring to fill (default 60)")
    ap.add_argument("--write", action="store_true", help="record the figures in bench/RESULTS.md")
    args = ap.parse_args(argv)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    stages = []
    for k, (label, _) in enumerate(STAGES):
        stages.append(stage(k))
        print(f"{label}: {stages[-1]['VmRSS']:.0f} MB", flush=True)
    idle = idle_server(args.settle)
    body = report(stages, idle, head)
    print(body)
    if args.write:
        replace_section(SECTION, body)


if __name__ == "__main__":
    main()
