"""Bounded load on the measuring service: N measurements from C concurrent clients on 127.0.0.1
while the live stream runs. Zero errors required; p50/p95 latency of POST /api/measure recorded
in bench/RESULTS.md "## Service load".

    .venv/bin/python bench/bench_service_load.py [--requests 500] [--clients 8] [--source SPEC] [--no-record]
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
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
from results_file import RESULTS, machine, replace_section

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## Service load"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(spec: str, db: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    cmd = [sys.executable, "-m", "service.cli", "serve", "--source", spec, "--port", str(port), "--db", str(db)]
    log = open(db.with_suffix(".log"), "w+b")  # a file, not a pipe nobody drains
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            log.seek(0)
            raise SystemExit(f"depthruler serve exited: {log.read().decode(errors='replace')}")
        try:
            if httpx.get(f"{base}/api/frames/latest", params={"wait": 2}, timeout=5).status_code == 200:
                return proc, base
        except httpx.TransportError:
            pass
        time.sleep(0.3)
    proc.terminate()
    raise SystemExit(f"no frame from {spec} within 90 s")


def segment_points(frame: dict, rng: np.random.Generator) -> tuple[list[float], list[float]]:
    """Two points on the target when the frame has ground truth, else across the image centre."""
    truth = frame.get("truth")
    if truth and truth.get("p1_px") and truth.get("p2_px"):
        a, b = np.array(truth["p1_px"]), np.array(truth["p2_px"])
        u1, u2 = rng.uniform(0.05, 0.4), rng.uniform(0.6, 0.95)
        return (a + (b - a) * u1).tolist(), (a + (b - a) * u2).tolist()
    w, h = frame["width"], frame["height"]
    return [w * rng.uniform(0.3, 0.45), h * rng.uniform(0.4, 0.6)], [w * rng.uniform(0.55, 0.7), h * rng.uniform(0.4, 0.6)]


def run_load(base: str, requests: int, clients: int, method: str, per_frame: int) -> dict:
    latencies: list[float] = []
    errors: list[str] = []
    frames_seen: set[int] = set()
    lock = threading.Lock()
    counter = iter(range(requests))

    def client(k: int) -> None:
        rng = np.random.default_rng(k)
        frame: dict = {}
        done = 0
        with httpx.Client(base_url=base, timeout=60) as http:
            while True:
                with lock:
                    if next(counter, None) is None:
                        break
                if done % per_frame == 0:  # like the page: freeze what is shown, then click and adjust
                    if frame:
                        http.delete(f"/api/frames/{frame['id']}/freeze")
                    frame = http.get("/api/frames/latest").json()
                    http.post(f"/api/frames/{frame['id']}/freeze").raise_for_status()
                done += 1
                p1, p2 = segment_points(frame, rng)
                body = {"frame_id": frame["id"], "p1": p1, "p2": p2, "options": {"method": method}}
                t0 = time.perf_counter()
                r = http.post("/api/measure", json=body)
                dt = time.perf_counter() - t0
                with lock:
                    frames_seen.add(frame["id"])
                    if r.status_code == 200:
                        latencies.append(dt)
                    else:
                        errors.append(f"{r.status_code} {r.text[:200]}")

    source_before = httpx.get(f"{base}/api/source").json()
    t0 = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(client, range(clients)))
    wall = time.perf_counter() - t0
    source_after = httpx.get(f"{base}/api/source").json()
    ms = np.array(latencies) * 1e3
    return {
        "requests": requests,
        "clients": clients,
        "per_frame": per_frame,
        "ok": len(latencies),
        "errors": errors,
        "p50_ms": float(np.percentile(ms, 50)) if ms.size else float("nan"),
        "p95_ms": float(np.percentile(ms, 95)) if ms.size else float("nan"),
        "max_ms": float(ms.max()) if ms.size else float("nan"),
        "throughput": len(latencies) / wall,
        "wall_s": wall,
        "frames_measured_on": len(frames_seen),
        "stream_frames": source_after["frames"] - source_before["frames"],
        "stream_fps": source_after["measured_fps"],
        "source_state": source_after["state"],
    }


def _row(r: dict) -> str:
    return (
        f"| {r['per_frame']} | {r['requests']} | {r['clients']} | {len(r['errors'])} | {r['p50_ms']:.1f} ms | "
        f"{r['p95_ms']:.1f} ms | {r['max_ms']:.1f} ms | {r['throughput']:.1f} req/s | {r['frames_measured_on']} | "
        f"{r['stream_frames']} frames ({r['stream_fps']:.1f} fps) |\n"
    )


def record(results: list[dict], spec: str, method: str, load: float) -> None:
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    first = results[0]
    body = (
        f"{SECTION}\n\n"
        f"`bench/bench_service_load.py`: {first['requests']} `POST /api/measure` from {first['clients']} concurrent "
        f"clients on 127.0.0.1 while the live stream runs (`{spec}`, method `{method}`). Each client behaves like the "
        "page: it freezes the latest frame, measures on it a number of times (a click and adjustments), then takes "
        "a new frame. Every measured frame is saved to the history (compressed .npz, written by a background "
        "thread with a bounded queue), which is what the tail latency pays for when many frames are measured. "
        "Latency is the measure request alone; a fresh server per row.\n\n"
        "| measurements per frame | requests | clients | errors | p50 | p95 | max | throughput | frames saved | stream during load |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n"
        + "".join(_row(r) for r in results)
        + f"\nMachine: {machine()}; {date}; 1-minute load average {load:.1f} before the run. The host is "
        "shared with other machines' jobs, so latencies are upper bounds.\n"
    )
    replace_section(SECTION, body)


def run_scenario(spec: str, requests: int, clients: int, method: str, per_frame: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        proc, base = start_server(spec, Path(tmp) / "load.db")
        try:
            return run_load(base, requests, clients, method, per_frame)
        finally:
            proc.terminate()  # a clean stop writes the queued history frames first
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--requests", type=int, default=500)
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--source", default="sim:poster?distance=3&seed=1&fps=10")
    ap.add_argument("--method", default="robust", choices=["robust", "paper", "basic"])
    ap.add_argument(
        "--per-frame", default="5,1000", help="comma-separated measurements per frozen frame, one run each (default 5,1000)"
    )
    ap.add_argument("--no-record", action="store_true", help="print only; leave bench/RESULTS.md alone")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()[0]
    results = []
    failed = False
    for per_frame in (int(v) for v in args.per_frame.split(",")):
        r = run_scenario(args.source, args.requests, args.clients, args.method, per_frame)
        results.append(r)
        print(
            f"{per_frame} per frame: {r['ok']}/{r['requests']} ok, {len(r['errors'])} errors; p50 {r['p50_ms']:.1f} ms, "
            f"p95 {r['p95_ms']:.1f} ms, max {r['max_ms']:.1f} ms; {r['throughput']:.1f} req/s; {r['frames_measured_on']} "
            f"frames saved; stream {r['stream_frames']} frames ({r['stream_fps']:.1f} fps), state {r['source_state']}"
        )
        for e in r["errors"][:5]:
            print("error:", e)
        failed |= bool(r["errors"])
    if failed:
        raise SystemExit(1)
    if not args.no_record:
        record(results, args.source, args.method, load_before)
        print(f"recorded in {RESULTS.relative_to(ROOT)} ({SECTION})")


if __name__ == "__main__":
    main()
