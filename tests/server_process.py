"""A real ``depthruler serve`` in a subprocess, for the tests that need one (browser, crash, full disk)."""

from __future__ import annotations

import errno
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_8000_taken() -> bool:
    """Whether port 8000, ``depthruler serve``'s default, is held on the IPv4 wildcard address."""
    try:
        with socket.create_server(("0.0.0.0", 8000)):
            return False
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            return True
        raise


def start_serve(
    source: str, db: Path, log: Path, *args: str, prefix: tuple[str, ...] = (), timeout_s: float = 60.0, token: str = ""
) -> tuple[subprocess.Popen, str]:
    """Start ``[PREFIX] depthruler serve --source SOURCE --db DB ARGS`` on a free port, its output
    appended to ``log``; return the process and its base URL once the first frame is served (asked
    with ``token`` when the server needs one). Raises
    AssertionError (with the log) when the server exits or gives no frame within ``timeout_s``."""
    port = free_port()
    cmd = [*prefix, sys.executable, "-m", "cli.main", "serve", "--source", source, "--port", str(port), "--db", str(db), *args]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    with open(log, "ab") as out:  # the child keeps its own handle
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, env=env)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"depthruler serve exited: {log.read_text(errors='replace')}")
        try:
            auth = {"Authorization": f"Bearer {token}"} if token else {}
            if httpx.get(f"{base}/api/frames/latest", params={"wait": 2}, headers=auth, timeout=5).status_code == 200:
                return proc, base
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise AssertionError(f"no frame from {source} within {timeout_s:g} s: {log.read_text(errors='replace')[-2000:]}")
