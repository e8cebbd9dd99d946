"""The tests do not depend on the host's port 8000 (``depthruler serve``'s default): with 8000 held by
another process on every IPv4 address, the tests that run or configure ``serve`` still pass (each
one that binds asks for a free port; the others must fail on their own input before the port check)."""

from __future__ import annotations

import errno
import re
import socket
import subprocess
import sys

import pytest

from server_process import ROOT

# Every test that runs ``serve`` through typer's CliRunner or parses its configuration.
SERVE_TESTS = ["tests/cli/test_cli.py", "tests/service/test_config.py", "tests/service/test_service_security.py"]
HOLD = (
    "import socket, sys\n"
    "s = socket.socket()\n"
    "s.bind(('0.0.0.0', 8000)); s.listen()\n"
    "print('held', flush=True); sys.stdin.read()\n"  # until the test closes our stdin
)


def _port_8000_taken() -> bool:
    try:
        with socket.create_server(("0.0.0.0", 8000)):
            return False
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            return True
        raise


@pytest.mark.slow
def test_serve_tests_pass_while_port_8000_is_held(tmp_path):
    holder = None
    if not _port_8000_taken():  # held already (another service on this host) is the case under test too
        holder = subprocess.Popen([sys.executable, "-c", HOLD], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        if holder is not None:
            assert holder.stdout.readline().strip() == "held", "could not hold port 8000"
        assert _port_8000_taken()
        run = subprocess.run(
            [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--basetemp", str(tmp_path / "t"), *SERVE_TESTS],
            cwd=ROOT, capture_output=True, text=True, timeout=900,
        )
    finally:
        if holder is not None:
            holder.stdin.close()
            holder.wait(10)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert re.search(r"^\d+ passed", run.stdout, re.M), run.stdout[-500:]
