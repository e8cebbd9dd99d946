"""Where an idle service's resident memory goes: the process built up stage by stage, with the
kernels built ahead of time and with numba's, and the idle server's mappings.

Each stage is a fresh interpreter that does everything up to that stage, with the server's
allocator settings (``service.connections.return_large_blocks``), and reports its resident set
(VmRSS, from /proc): the scientific base (numpy, scipy.special, OpenCV), the measuring kernels
loaded and warmed up (``measure.warm_up``: the module built ahead of time, or numba's just-in-time
kernels with ``DEPTHRULER_KERNELS=jit``, which bring numba, LLVM and numba's runtime), the service's
modules, and the default simulator open with three frames read one after another, as the capture
thread reads them. Then `depthruler serve` at its defaults (the simulator) is left idle until its
ring is full, and its mappings are grouped: LLVM's library (``libllvmlite.so``, absent with the
built kernels), the other mapped files, the heap and anonymous mappings. Figures go to
bench/RESULTS.md "## Service memory".

    python bench/bench_memory.py [--settle 60] [--write]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from bench.bench_service_load import idle_default_server, rss_mb
from bench.results_file import machine, replace_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Service memory"

# (label, code run after the previous stages' code), cumulative
STAGES = [
    ("Python, numpy, scipy.special, OpenCV", "import numpy, scipy.special, cv2"),
    ("+ the measuring kernels loaded and warmed up", "import measure; measure.warm_up()"),
    ("+ the service's modules", "import service.app"),
    ("+ the default simulator open, 3 frames read one after another (the last one kept)",
     "from device import open_source; src = open_source('sim?fps=0'); src.open()\nfor _ in range(3): frame = src.read()"),
]
KERNELS = {"built ahead of time": "auto", "numba's (just in time)": "jit"}
# The stage's own RSS, read with what it imported already (importing a bench module would add its imports).
_PRINT_RSS = "print(next(int(line.split()[1]) for line in open('/proc/self/status') if line.startswith('VmRSS:')) / 1024)"


def stage(k: int, kernels: str) -> float:
    """RSS (MB) of a fresh interpreter that ran stages 0..k with ``DEPTHRULER_KERNELS=kernels``."""
    code = "\n".join(
        ["from service.connections import return_large_blocks", "return_large_blocks()"]
        + [c for _, c in STAGES[: k + 1]]
        + [_PRINT_RSS]
    )
    env = {**os.environ, "DEPTHRULER_KERNELS": kernels}
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, check=True)
    return float(res.stdout.strip().splitlines()[-1])


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
        return {"rss_mb": rss_mb(proc.pid), "mappings": mappings_mb(proc.pid), "ring_mb": health["ring_bytes"] / 1e6,
                "kernels": health["kernels"]}  # fmt: skip


def report(stages: dict[str, list[float]], idle: dict, head: str) -> str:
    names = list(stages)
    rows = []
    for k, (label, _) in enumerate(STAGES):
        cells = []
        for name in names:
            now, before = stages[name][k], stages[name][k - 1] if k else 0.0
            cells.append(f"{now:.0f} ({now - before:+.0f})")
        rows.append(f"| {label} | {' | '.join(cells)} |\n")
    maps = "".join(f"| {k} | {v:.0f} |\n" for k, v in sorted(idle["mappings"].items(), key=lambda kv: -kv[1]))
    return (
        f"{SECTION}\n\n`bench/bench_memory.py` (`depthruler bench memory --write`) on {head}: a process built up stage by stage "
        "(a fresh interpreter per cell, with the server's allocator settings), resident memory in MB (VmRSS; in brackets "
        "the stage's step), with the measuring kernels built ahead of time (the default where a C compiler is present) "
        "and with numba's just-in-time kernels (`DEPTHRULER_KERNELS=jit`).\n\n"
        f"| stage | {' | '.join(f'kernels {n}' for n in names)} |\n| --- |{' --- |' * len(names)}\n" + "".join(rows)
        + f"\n`depthruler serve` at its defaults (the simulator, kernels as it chose them: {idle['kernels']}), idle until its "
        f"ring is full: RSS {idle['rss_mb']:.0f} MB (ring {idle['ring_mb']:.0f} MB by /api/health), its resident pages "
        "by mapping (MB):\n\n| mapping | MB |\n| --- | --- |\n" + maps
        + f"\nMachine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n"
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--settle", type=float, default=60.0, help="seconds at most for the idle server's ring to fill (default 60)")
    ap.add_argument("--write", action="store_true", help="record the figures in bench/RESULTS.md")
    args = ap.parse_args(argv)
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    stages: dict[str, list[float]] = {}
    for name, kernels in KERNELS.items():
        stages[name] = []
        for k, (label, _) in enumerate(STAGES):
            stages[name].append(stage(k, kernels))
            print(f"kernels {name}: {label}: {stages[name][-1]:.0f} MB", flush=True)
    idle = idle_server(args.settle)
    body = report(stages, idle, head)
    print(body)
    if args.write:
        replace_section(SECTION, body)


if __name__ == "__main__":
    main()
