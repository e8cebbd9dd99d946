"""Slow HTTP clients against a server on this machine: connections that send their headers, or their
body, a little at a time, while health is polled; how long the server kept each, and health's latency.

``python tests/integration/slow_clients.py --server KIND`` starts the service under KIND (uvicorn-h11,
uvicorn-httptools, hypercorn, depthruler) on a free loopback port and measures it
(docs/decisions/connection-limits.md has what it found). The tests import :func:`flood`.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class FloodResult:
    """Seconds each connection stayed open (None: still open when the flood stopped), health's
    latencies (s, None for a failed probe), the status line of the server's last answer on each
    connection (b"" when it closed without one), and the flood's duration (s)."""

    header_open_s: list[float | None]
    body_open_s: list[float | None]
    header_answers: list[bytes]
    body_answers: list[bytes]
    health_s: list[float | None]
    duration_s: float
    refused: int = 0
    statuses: dict[str, int] = field(default_factory=dict)

    def summary(self) -> dict[str, object]:
        def spread(xs: list[float | None]) -> dict[str, object]:
            closed = sorted(x for x in xs if x is not None)
            return {
                "connections": len(xs),
                "still_open": sum(x is None for x in xs),
                "closed_after_s_min": round(closed[0], 2) if closed else None,
                "closed_after_s_max": round(closed[-1], 2) if closed else None,
            }

        ok = sorted(h for h in self.health_s if h is not None)
        return {
            "slow_headers": spread(self.header_open_s),
            "slow_bodies": spread(self.body_open_s),
            "answers": self.statuses,
            "health_probes": len(self.health_s),
            "health_failed": sum(h is None for h in self.health_s),
            "health_max_s": round(ok[-1], 3) if ok else None,
            "health_median_s": round(ok[len(ok) // 2], 4) if ok else None,
            "refused_connects": self.refused,
            "duration_s": round(self.duration_s, 1),
        }


def raise_fd_limit(needed: int) -> None:
    """Raise this process's soft limit on open files to ``needed`` (up to the hard limit)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < needed:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(needed, hard), hard))


async def _slow(host: str, port: int, head: bytes, drip: bytes, interval_s: float, stop_at: float) -> tuple[float | None, bytes, bool]:
    """One connection: send ``head``, then ``drip`` every ``interval_s`` until the server closes it or
    ``stop_at`` (monotonic). How long it stayed open (None: still open), the server's status line."""
    t0 = time.monotonic()
    try:
        reader, writer = await asyncio.open_connection(host, port)
    except OSError:
        return 0.0, b"", True
    answer = b""
    try:
        writer.write(head)
        await writer.drain()
        while time.monotonic() < stop_at:
            try:
                data = await asyncio.wait_for(reader.read(4096), min(interval_s, max(0.01, stop_at - time.monotonic())))
            except asyncio.TimeoutError:
                try:
                    writer.write(drip)
                    await writer.drain()
                except OSError:
                    return time.monotonic() - t0, answer, False
                continue
            except OSError:
                return time.monotonic() - t0, answer, False
            if not data:
                return time.monotonic() - t0, answer, False
            answer = answer or data.split(b"\r\n", 1)[0]
        return None, answer, False
    finally:
        writer.close()


def _health(base: str, every_s: float, done: Callable[[], bool]) -> list[float | None]:
    """Health's latency (s; None: failed), a new connection per probe, every ``every_s`` until ``done()``."""
    out: list[float | None] = []
    with httpx.Client(base_url=base, timeout=5.0, limits=httpx.Limits(max_keepalive_connections=0)) as http:
        while not done():
            t0 = time.monotonic()
            try:
                r = http.get("/api/health")
                out.append(time.monotonic() - t0 if r.status_code == 200 else None)
            except httpx.HTTPError:
                out.append(None)
            time.sleep(max(0.0, every_s - (time.monotonic() - t0)))
    return out


async def _flood(
    host: str, port: int, headers: int, bodies: int, interval_s: float, duration_s: float, ramp_s: float, token: str
) -> list[tuple[float | None, bytes, bool]]:
    """Open ``headers`` slow-header and ``bodies`` slow-body connections within ``ramp_s`` and drip a
    byte or a header line every ``interval_s`` on each for ``duration_s``; the bodies' requests carry
    ``token`` (a header is never complete, so it carries none)."""
    start = time.monotonic()
    stop_at = start + duration_s
    host_line = f"Host: {host}:{port}\r\n".encode()
    head = b"GET /api/health HTTP/1.1\r\n" + host_line
    auth = f"Authorization: Bearer {token}\r\n".encode() if token else b""
    body_head = (
        b"POST /api/measure HTTP/1.1\r\n" + host_line + auth + b"Content-Type: application/json\r\nContent-Length: 4000\r\n\r\n{"
    )

    async def later(k: int, n: int, coro_args: tuple) -> tuple[float | None, bytes, bool]:
        await asyncio.sleep(ramp_s * k / max(1, n))
        return await _slow(host, port, *coro_args)

    n = headers + bodies
    tasks = [asyncio.ensure_future(later(k, n, (head, b"X-Slow: 1\r\n", interval_s, stop_at))) for k in range(headers)]
    tasks += [asyncio.ensure_future(later(headers + k, n, (body_head, b" ", interval_s, stop_at))) for k in range(bodies)]
    return list(await asyncio.gather(*tasks))


def _flood_process(*args: object) -> list[tuple[float | None, bytes, bool]]:
    raise_fd_limit(int(args[2]) + int(args[3]) + 256)  # type: ignore[call-overload]
    return asyncio.run(_flood(*args))  # type: ignore[arg-type]


def flood(
    host: str, port: int, *, headers: int, bodies: int, interval_s: float, duration_s: float, health_every_s: float = 0.2,
    ramp_s: float = 1.0, token: str = "",
) -> FloodResult:  # fmt: skip
    """The slow connections of :func:`_flood` from a process of their own (so that their event loop
    does not delay the probes), and health probed from this one meanwhile."""
    start = time.monotonic()
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        running = pool.submit(_flood_process, host, port, headers, bodies, interval_s, duration_s, ramp_s, token)
        probes = _health(f"http://{host}:{port}", health_every_s, running.done)
        results = running.result(timeout=duration_s + 120)
    statuses: dict[str, int] = {}
    for _, answer, _ in results:
        key = answer.decode("latin-1") or "closed without an answer"
        statuses[key] = statuses.get(key, 0) + 1
    return FloodResult(
        header_open_s=[r[0] for r in results[:headers]],
        body_open_s=[r[0] for r in results[headers:]],
        header_answers=[r[1] for r in results[:headers]],
        body_answers=[r[1] for r in results[headers:]],
        health_s=probes,
        duration_s=time.monotonic() - start,
        refused=sum(r[2] for r in results),
        statuses=statuses,
    )


_SERVERS = {
    # The same app on each server, with its idle keep-alive timeout and, where the server has one, a read timeout.
    "uvicorn-h11": "import uvicorn; uvicorn.run(APP, host='127.0.0.1', port=PORT, http='h11', timeout_keep_alive=T, log_level='error')",
    "uvicorn-httptools": "import uvicorn; uvicorn.run(APP, host='127.0.0.1', port=PORT, http='httptools', timeout_keep_alive=T, log_level='error')",
    "hypercorn": (
        "import asyncio; from hypercorn.config import Config; from hypercorn.asyncio import serve\n"
        "c = Config(); c.bind = [f'127.0.0.1:{PORT}']; c.keep_alive_timeout = T; c.read_timeout = T; c.loglevel = 'ERROR'\n"
        "asyncio.run(serve(APP, c))"
    ),
}


def _start(kind: str, port: int, timeout_s: float, db: Path) -> subprocess.Popen:
    if kind == "depthruler":
        cmd = [sys.executable, "-m", "cli.main", "serve", "--source", "sim:poster?width=320&height=240", "--port", str(port),
               "--db", str(db), "--header-timeout", str(timeout_s), "--body-timeout", str(timeout_s), "--keep-alive", str(timeout_s)]  # fmt: skip
    else:
        app = f"from service.app import create_app; APP = create_app('sim:poster?width=320&height=240', db_path={str(db)!r})\n"
        code = app + _SERVERS[kind].replace("PORT", str(port)).replace("T", repr(timeout_s) if kind == "hypercorn" else str(int(timeout_s)))
        cmd = [sys.executable, "-c", code]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--server", choices=[*_SERVERS, "depthruler"], required=True)
    parser.add_argument("--headers", type=int, default=1000)
    parser.add_argument("--bodies", type=int, default=500)
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between two bytes of a slow client")
    parser.add_argument("--timeout", type=float, default=3.0, help="the server's header/body/keep-alive timeouts (s)")
    parser.add_argument("--duration", type=float, default=15.0)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "tests"))
    from server_process import free_port

    port = free_port()
    with tempfile.TemporaryDirectory(prefix="depthruler-slow-") as tmp:
        proc = _start(args.server, port, args.timeout, Path(tmp) / "h.db")
        try:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                try:
                    if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=2).status_code == 200:
                        break
                except httpx.HTTPError:
                    time.sleep(0.2)
            result = flood("127.0.0.1", port, headers=args.headers, bodies=args.bodies, interval_s=args.interval, duration_s=args.duration)
        finally:
            proc.terminate()
            proc.wait(30)
    print(json.dumps({"server": args.server, "interval_s": args.interval, "timeout_s": args.timeout, **result.summary()}, indent=1))


if __name__ == "__main__":
    main()
