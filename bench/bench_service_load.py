"""Page-like load on the measuring service, this code against a baseline revision in the same run.

Each of C clients (C = 1, 4, 8) behaves like the web page driven by a person: it freezes the
latest frame, waits a think time (the second click), measures, re-reads the history list
(`GET /api/measurements?limit=100`) and the new thumbnail, and measures again after another think
time; after ``per_frame`` measurements it unfreezes and takes a new frame. Two load shapes: a new
frame for every measurement (``per_frame`` 1: every measurement saves a frame) and five
measurements per frozen frame. Meanwhile one viewer follows the live stream as the page does
(long-poll `GET /api/frames/latest?after=&wait=` then the frame's JPEG; PNG on a server without
JPEG), and its frame rate is compared with the source's; a prober times the live frame and
health every 100 ms. Then, on a server over a history of ``--exports`` measurements, the CSV and
JSON exports are downloaded while the prober runs; and a server at its defaults is left idle until
its ring is full, for its resident memory.

The baseline (``--baseline REV``, default the service before its load work) is extracted with
`git archive` into a temporary folder and served from there, one server at a time, with the same
source and load. Latency percentiles are of `POST /api/measure` alone; the list and thumbnail
requests are reported by their p95. Figures go to bench/RESULTS.md "## Service load".

    python bench/bench_service_load.py [--per-client 30] [--clients 1,8,32] [--exports 10000] [--rss 60] [--baseline REV] [--no-record]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import httpx
import numpy as np
from bench.bench_export import fill
from bench.load_probes import Prober, Viewer, _probe, pct  # noqa: F401  (_probe: the prober process's entry)
from bench.results_file import RESULTS, machine, replace_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Service load"
BASELINE = "f746d95"  # the service before its load work (unbounded measurements, whole exports)
JSON = {"Content-Type": "application/json"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(code: Path, spec: str, db: Path) -> tuple[subprocess.Popen, str]:
    """`depthruler serve` of the code in ``code`` on a free loopback port; waits for a first frame."""
    port = free_port()
    # the command-line module of that revision (it moved from service/ to cli/)
    entry = next(m for m in ("cli/main.py", "service/cli.py") if (code / m).is_file())
    cmd = [sys.executable, "-m", entry.removesuffix(".py").replace("/", "."), "serve", "--source", spec, "--port", str(port), "--db", str(db)]
    log = open(db.with_suffix(".log"), "w+b")  # a file, not a pipe nobody drains
    env = {**os.environ, "PYTHONPATH": str(code)}
    proc = subprocess.Popen(cmd, cwd=code, stdout=log, stderr=subprocess.STDOUT, env=env)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            log.seek(0)
            raise SystemExit(f"depthruler serve ({code}) exited: {log.read().decode(errors='replace')}")
        try:
            if httpx.get(f"{base}/api/frames/latest", params={"wait": 2}, timeout=5).status_code == 200:
                return proc, base
        except httpx.TransportError:
            pass
        time.sleep(0.3)
    proc.terminate()
    raise SystemExit(f"no frame from {spec} within 120 s")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far (all its threads), from /proc; NaN elsewhere."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def stop_server(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()


def segment_points(frame: dict, rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """Two points on the target when the frame has ground truth, else across the image centre."""
    truth = frame.get("truth")
    if truth and truth.get("p1_px") and truth.get("p2_px"):
        a, b = np.array(truth["p1_px"]), np.array(truth["p2_px"])
        u1, u2 = rng.uniform(0.05, 0.4), rng.uniform(0.6, 0.95)
        return (a + (b - a) * u1).tolist(), (a + (b - a) * u2).tolist()
    w, h = frame["width"], frame["height"]
    return [w * rng.uniform(0.3, 0.45), h * rng.uniform(0.4, 0.6)], [w * rng.uniform(0.55, 0.7), h * rng.uniform(0.4, 0.6)]


def rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` (MB, from /proc); NaN elsewhere."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def run_exports(base: str) -> list[dict]:
    """Download the CSV and then the JSON export while a :class:`Prober` times the live frame and
    health; the export's wall time and size, the probes' percentiles during it."""
    rows = []
    for kind in ("csv", "json"):
        prober = Prober(base, 0.05)
        prober.start()
        time.sleep(2.0)  # the prober process has started
        live0, health0 = prober.counts()
        t0, size = time.perf_counter(), 0
        with httpx.stream("GET", f"{base}/api/measurements.{kind}", timeout=600) as r:
            for chunk in r.iter_bytes():
                size += len(chunk)
        wall = time.perf_counter() - t0
        prober.finish()
        health, live = prober.health_ms[health0:], prober.live_ms[live0:]
        rows.append({"kind": kind.upper(), "status": r.status_code, "export_s": wall, "mb": size / 1e6, "probes": len(health),
                     "health_p50": pct(health, 50), "health_p99": pct(health, 99), "health_max": max(health, default=float("nan")),
                     "live_p95": pct(live, 95)})  # fmt: skip
    return rows


def run_load(
    base: str, clients: int, per_client: int, per_frame: int, think_s: tuple[float, float], method: str, pid: int = 0,
    late: int = 0, late_s: float = 0.0,
) -> dict:
    measure_ms: list[float] = []
    list_ms: list[float] = []
    thumb_ms: list[float] = []
    errors: list[str] = []
    busy = [0]
    lock = threading.Lock()

    def timed(http: httpx.Client, method_: str, url: str, into: list[float], **kw) -> httpx.Response:
        """The request, timed; a 429 is counted as busy and tried again after its Retry-After, as the
        page does, and the attempt that is answered is the one timed."""
        while True:
            t0 = time.perf_counter()
            r = http.request(method_, url, **kw)
            dt = (time.perf_counter() - t0) * 1e3
            if r.status_code != 429:
                break
            with lock:
                busy[0] += 1
            time.sleep(float(r.headers.get("Retry-After", "1")))
        with lock:
            if r.status_code == 200:
                into.append(dt)
            else:
                errors.append(f"{method_} {url}: {r.status_code} {r.text[:160]}")
        return r

    paths = httpx.get(f"{base}/openapi.json", timeout=30).json()["paths"]
    thumb = "thumb.jpg" if any(p.endswith("/thumb.jpg") for p in paths) else "thumb.png"  # PNG on older servers

    def client(k: int) -> None:
        rng = np.random.default_rng(k)
        frame: dict = {}
        with httpx.Client(base_url=base, timeout=60, headers=JSON) as http:
            for done in range(per_client):
                if done % per_frame == 0:
                    if frame:
                        http.delete(f"/api/frames/{frame['id']}/freeze")
                    frame = http.get("/api/frames/latest").json()
                    http.post(f"/api/frames/{frame['id']}/freeze").raise_for_status()
                time.sleep(rng.uniform(*think_s))  # the next click or handle adjustment
                p1, p2 = segment_points(frame, rng)
                body = {"frame_id": frame["id"], "p1": p1, "p2": p2, "options": {"method": method}}
                r = timed(http, "POST", "/api/measure", measure_ms, json=body)
                if r.status_code != 200:
                    continue
                timed(http, "GET", "/api/measurements?limit=100", list_ms)
                # once, as the page does: the request that draws it
                timed(http, "GET", f"/api/measurements/{r.json()['id']}/{thumb}", thumb_ms)

    late_status: list[int] = []

    def late_client(k: int) -> None:
        """A person who freezes a frame and measures on it at late_s/4, late_s/2 and late_s after the
        freeze (never unfreezing in between) while the others load the service: each 410 is a frame
        the service let go within a measurement session."""
        rng = np.random.default_rng(1000 + k)
        with httpx.Client(base_url=base, timeout=60, headers=JSON) as http:
            frame = http.get("/api/frames/latest").json()
            http.post(f"/api/frames/{frame['id']}/freeze").raise_for_status()
            frozen_at = time.monotonic()
            for at in (late_s / 4, late_s / 2, late_s):
                time.sleep(max(0.0, frozen_at + at - time.monotonic()))
                p1, p2 = segment_points(frame, rng)
                body = {"frame_id": frame["id"], "p1": p1, "p2": p2, "options": {"method": method}}
                while (r := http.post("/api/measure", json=body)).status_code == 429:
                    time.sleep(float(r.headers.get("Retry-After", "1")))
                with lock:
                    late_status.append(r.status_code)
            http.delete(f"/api/frames/{frame['id']}/freeze")

    viewer, prober = Viewer(base), Prober(base)
    viewer.start()
    prober.start()
    time.sleep(2.0)  # the viewer has caught up with the stream, the prober's process has started
    probed = prober.counts()
    lates = [threading.Thread(target=late_client, args=(k,), daemon=True) for k in range(late if late_s > 0 else 0)]
    for t in lates:
        t.start()
    rss0 = rss_mb(pid) if pid else float("nan")
    source_before = httpx.get(f"{base}/api/source").json()
    shown0 = viewer.shown
    cpu0 = cpu_seconds(pid) if pid else float("nan")
    t0 = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(client, range(clients)))
    wall = time.perf_counter() - t0
    cpu = (cpu_seconds(pid) if pid else float("nan")) - cpu0
    viewer.stop.set()
    prober.finish()
    viewer.join(10)
    source_after = httpx.get(f"{base}/api/source").json()
    for t in lates:
        t.join(late_s + 120)
    stream_frames = source_after["frames"] - source_before["frames"]
    ms = np.array(measure_ms)

    return {
        "clients": clients,
        "per_frame": per_frame,
        "requests": clients * per_client,
        "ok": len(ms),
        "errors": errors,
        "busy": busy[0],
        "late": (sum(s == 200 for s in late_status), sum(s == 410 for s in late_status), len(late_status)),
        "p50_ms": pct(ms, 50),
        "p95_ms": pct(ms, 95),
        "p99_ms": pct(ms, 99),
        "list_p95_ms": pct(list_ms, 95),
        "thumb_p95_ms": pct(thumb_ms, 95),
        "throughput": len(ms) / wall,
        # the server process's CPU over the run (requests, the source's rendering, the live view's
        # JPEGs, saving frames) per measurement: steadier than latency on a shared host
        "cpu_ms_per_measure": cpu / max(1, len(ms)) * 1e3,
        "view_fps": (viewer.shown - shown0) / wall,
        "source_fps": stream_frames / wall,
        "live_p95_ms": pct(prober.live_ms[probed[0] :], 95),
        "health_p99_ms": pct(prober.health_ms[probed[1] :], 99),
        "rss_mb": (rss0, rss_mb(pid) if pid else float("nan")),
    }


def extract(rev: str, into: Path) -> Path:
    """The tree of ``rev`` (git archive: the repository is left as it is) in ``into``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", rev], check=True, capture_output=True).stdout
    into.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


@contextmanager
def idle_default_server(code: Path, tmp: Path, settle_s: float) -> Iterator[tuple[subprocess.Popen, dict]]:
    """`depthruler serve` of ``code`` at its defaults (the simulator), left idle until its ring stops
    growing (``settle_s`` at most): the process and its last /api/health answer; stopped afterwards."""
    proc, base = start_server(code, "sim", tmp / "idle.db")
    try:
        deadline, frames = time.monotonic() + settle_s, -1
        while time.monotonic() < deadline:
            time.sleep(2.0)
            health = httpx.get(f"{base}/api/health", timeout=60).json()
            if health["frames"] == frames:
                break  # the ring stopped growing: full
            frames = health["frames"]
        yield proc, health
    finally:
        stop_server(proc)


def idle_rss(code: Path, tmp: Path, settle_s: float) -> dict:
    """The idle default server's RSS (MB) and what /api/health says the ring holds."""
    with idle_default_server(code, tmp, settle_s) as (proc, health):
        return {"rss_mb": rss_mb(proc.pid), "frames": health["frames"], "ring_mb": health.get("ring_bytes", float("nan")) / 1e6}


def run_version(code: Path, spec: str, shapes: list[int], clients: list[int], args: argparse.Namespace) -> dict:
    out: dict = {"load": [], "exports": [], "idle": None}
    with tempfile.TemporaryDirectory() as tmp:
        if args.rss:
            out["idle"] = idle_rss(code, Path(tmp), args.rss)
            print(f"  idle at defaults: RSS {out['idle']['rss_mb']:.0f} MB, {out['idle']['frames']} frames in the ring", flush=True)
        if clients:
            proc, base = start_server(code, spec, Path(tmp) / "load.db")
            try:
                for per_frame in shapes:
                    for c in clients:
                        late = (args.late, args.late_s) if c == max(clients) else (0, 0.0)
                        r = run_load(base, c, args.per_client, per_frame, (args.think_min, args.think_max), args.method, proc.pid, *late)
                        print(
                            f"  {c} clients, {per_frame}/frame: {r['ok']}/{r['requests']} ok, {len(r['errors'])} errors, {r['busy']} busy; "
                            f"measure p50 {r['p50_ms']:.1f} / p95 {r['p95_ms']:.1f} / p99 {r['p99_ms']:.1f} ms; list p95 "
                            f"{r['list_p95_ms']:.1f} ms, thumb p95 {r['thumb_p95_ms']:.1f} ms; live frame p95 {r['live_p95_ms']:.1f} ms, "
                            f"health p99 {r['health_p99_ms']:.1f} ms; live view {r['view_fps']:.1f} fps "
                            f"of the source's {r['source_fps']:.1f}; server CPU {r['cpu_ms_per_measure']:.1f} ms per measurement; "
                            f"RSS {r['rss_mb'][0]:.0f} -> {r['rss_mb'][1]:.0f} MB; late measurements ok / 410 / all {r['late']}",
                            flush=True,
                        )
                        for e in r["errors"][:3]:
                            print("  error:", e)
                        out["load"].append(r)
            finally:
                stop_server(proc)
        if args.exports:
            db = Path(tmp) / "export.db"
            fill(db, args.exports)
            proc, base = start_server(code, spec, db)
            try:
                for r in run_exports(base):
                    print(f"  {r['kind']} export of {args.exports}: {r['status']}, {r['mb']:.1f} MB in {r['export_s']:.1f} s; "
                          f"health p50 / p99 / max {r['health_p50']:.0f} / {r['health_p99']:.0f} / {r['health_max']:.0f} ms "
                          f"({r['probes']} probes), live frame p95 {r['live_p95']:.0f} ms", flush=True)  # fmt: skip
                    out["exports"].append(r)
            finally:
                stop_server(proc)
    return out


def _row(name: str, r: dict) -> str:
    return (
        f"| {name} | {r['per_frame']} | {r['clients']} | {r['ok']}/{r['requests']} | {len(r['errors'])} | {r['busy']} | {r['p50_ms']:.1f} | "
        f"{r['p95_ms']:.1f} | {r['p99_ms']:.1f} | {r['list_p95_ms']:.1f} | {r['thumb_p95_ms']:.1f} | {r['live_p95_ms']:.1f} | "
        f"{r['health_p99_ms']:.1f} | {r['view_fps']:.1f} / {r['source_fps']:.1f} | {r['cpu_ms_per_measure']:.1f} | {r['rss_mb'][1]:.0f} | "
        f"{_late(r)} |\n"
    )


def _late(r: dict) -> str:
    ok, gone, n = r["late"]
    return f"{ok} / {gone} of {n}" if n else ""


def _ratios(results: dict[str, dict], head: str, baseline: str) -> str:
    """Per code and load shape: the live-frame p95 at the most clients over its 1-client value."""
    lines = []
    for name, key in ((f"baseline {baseline}", "baseline"), (f"this ({head})", "this")):
        rows = (results.get(key) or {}).get("load") or []
        for per_frame in sorted({r["per_frame"] for r in rows}):
            shape = sorted((r for r in rows if r["per_frame"] == per_frame), key=lambda r: r["clients"])
            if len(shape) > 1 and shape[0]["clients"] == 1:
                top = shape[-1]
                lines.append(f"{name}, {per_frame} per frame: live p95 {top['clients']} clients / 1 client = "
                             f"{top['live_p95_ms']:.1f} / {shape[0]['live_p95_ms']:.1f} ms = {top['live_p95_ms'] / shape[0]['live_p95_ms']:.1f}x")
    return "".join(f"- {line}\n" for line in lines)


def _export_row(name: str, r: dict) -> str:
    return (
        f"| {name} | {r['kind']} | {r['status']} | {r['mb']:.1f} | {r['export_s']:.1f} | {r['health_p50']:.0f} | {r['health_p99']:.0f} | "
        f"{r['health_max']:.0f} | {r['live_p95']:.0f} |\n"
    )


def _pairs(results: dict[str, dict], part: str, head: str, baseline: str, row) -> str:
    """The rows of ``part``, each of this code right after the baseline's same row."""
    this, base = results["this"][part], (results.get("baseline") or {}).get(part) or []
    lines = []
    for i, r in enumerate(this):
        if i < len(base):
            lines.append(row(f"baseline {baseline}", base[i]))
        lines.append(row(f"this ({head})", r))
    return "".join(lines)


def record(results: dict[str, dict], args: argparse.Namespace, loads: list[float], head: str) -> None:
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    body = (
        f"{SECTION}\n\n"
        f"`bench/bench_service_load.py` (`depthruler bench service_load`): page-like load on `{args.source}`, method "
        f"`{args.method}`. Each client freezes the latest frame, waits {args.think_min * 1e3:.0f}-{args.think_max * 1e3:.0f} ms "
        "(a person's next click), measures, then reads the history list (`?limit=100`) and the thumbnail, as the page "
        f"does; {args.per_client} measurements per client; after `per frame` measurements it takes a new frame (1: every "
        "measurement saves a frame; 5: a click and four adjustments). A 429 (`busy`) is tried again after its "
        "`Retry-After`, as the page does. One viewer follows the live stream meanwhile "
        "(long-poll + JPEG), and a prober in a process of its own, every 100 ms, times the live frame (`GET /api/frames/latest` "
        "then its JPEG: `live p95`) and `GET /api/health` (`health p99`). At the most clients, "
        f"{args.late} more clients each freeze a frame and measure on it {args.late_s / 4:.0f}, {args.late_s / 2:.0f} and "
        f"{args.late_s:.0f} s later (`late ok / 410`). Latency (ms) is `POST /api/measure` alone (the "
        "answered attempt); the list and thumbnail columns are their p95; the server's CPU time (all its threads) is "
        "divided by the measurements, the steadier figure on a shared host; RSS (MB) at the end of the row. The baseline "
        "revision runs from `git archive` in the same run, one server at a time. Targets: 32 clients, live "
        "p95 <= 3x its 1-client value, health p99 < 100 ms, no 410.\n\n"
        "| code | per frame | clients | ok | errors | busy | p50 | p95 | p99 | list p95 | thumb p95 | live p95 | health p99 | "
        "live view / source fps | server CPU ms / measurement | RSS MB | late ok / 410 |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n"
        + _pairs(results, "load", head, args.baseline, _row)
        + "\nLive-frame p95 at the most clients over its 1-client value (target <= 3x):\n\n" + _ratios(results, head, args.baseline)
    )
    if results["this"]["exports"]:
        body += (
            f"\nExports of a history of {args.exports:,} measurements (`bench_export.fill`: real results, 60-400 samples each), "
            "downloaded whole while a prober times health and the live frame every 50 ms (target: health p99 < 200 ms).\n\n"
            "| code | export | status | MB | s | health p50 | health p99 | health max | live p95 |\n"
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n" + _pairs(results, "exports", head, args.baseline, _export_row)
        )
    if results["this"]["idle"]:
        idle = [(f"baseline {args.baseline}", results["baseline"]["idle"])] if results.get("baseline") else []
        idle.append((f"this ({head})", results["this"]["idle"]))
        body += (
            "\n`depthruler serve` at its defaults (the simulator), idle until its ring is full: resident memory "
            "(target: at most half of the baseline's).\n\n| code | RSS MB | frames in the ring | ring MB (health) |\n| --- | --- | --- | --- |\n"
            + "".join(f"| {n} | {r['rss_mb']:.0f} | {r['frames']} | {r['ring_mb']:.0f} |\n" for n, r in idle)
        )
    body += (
        f"\nMachine: {machine()}; {date}. The machine was shared with other engineers' jobs during the run: "
        f"1-minute load average {loads[0]:.1f} before, {loads[1]:.1f} after the baseline, {loads[-1]:.1f} at the end.\n"
    )
    replace_section(SECTION, body)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--per-client", type=int, default=30, help="measurements per client (default 30)")
    ap.add_argument("--clients", default="1,8,32", help="client counts, one row each (default 1,8,32; '' for none)")
    ap.add_argument("--per-frame", default="1,5", help="measurements per frozen frame, one load shape each (default 1,5)")
    ap.add_argument("--think-min", type=float, default=0.1, help="think time between clicks, seconds (default 0.1-0.3)")
    ap.add_argument("--think-max", type=float, default=0.3)
    ap.add_argument("--source", default="sim:poster?distance=3&seed=1&fps=10")
    ap.add_argument("--method", default="robust", choices=["robust", "paper", "basic"])
    ap.add_argument("--exports", type=int, default=10_000, help="history size for the export rows (default 10000; 0: none)")
    ap.add_argument("--late", type=int, default=4, help="clients at the most-clients row that measure long after freezing (default 4)")
    ap.add_argument("--late-s", type=float, default=55.0, help="their last measurement, seconds after the freeze (default 55; 0: none)")
    ap.add_argument("--rss", type=float, default=60.0, help="seconds at most for an idle default server's ring to fill (default 60; 0: skip)")
    ap.add_argument("--baseline", default=BASELINE, help=f"revision to compare against (default {BASELINE}); '' for none")
    ap.add_argument("--no-record", action="store_true", help="print only; leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)
    shapes = [int(v) for v in args.per_frame.split(",")]
    clients = [int(v) for v in args.clients.split(",") if v]
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    loads = [os.getloadavg()[0]]
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        if args.baseline:
            print(f"baseline {args.baseline}:", flush=True)
            results["baseline"] = run_version(extract(args.baseline, Path(tmp) / "baseline"), args.source, shapes, clients, args)
            loads.append(os.getloadavg()[0])
        print(f"this code ({head}, working tree):", flush=True)
        results["this"] = run_version(ROOT, args.source, shapes, clients, args)
    loads.append(os.getloadavg()[0])
    if not args.no_record:
        record(results, args, loads, head)
        print(f"recorded in {RESULTS.relative_to(ROOT)} ({SECTION})")
    if any(r["errors"] for r in results["this"]["load"]):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
