"""The tests do not depend on the host's port 8000 (``depthruler serve``'s default): with 8000 held by
another process on every IPv4 address, the tests that run or configure ``serve`` still pass (each
one that binds asks for a free port; the others must fail on their own input before the port check).

Those tests hold 8000 themselves while they run (the ``port_8000_held`` fixture of tests/conftest.py),
so in a run that collects them their own results are the check and they are not run a second time:
this test makes sure every one of them holds it. Those a run does not collect (``pytest
tests/integration``) it runs in a pytest of their own, with 8000 held by this one."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from server_process import ROOT, port_8000_taken

# Every test that runs ``serve`` through typer's CliRunner or parses its configuration.
SERVE_TESTS = ["tests/cli/test_cli.py", "tests/service/test_config.py", "tests/service/test_service_security.py"]


@pytest.mark.slow
def test_serve_tests_pass_while_port_8000_is_held(request, tmp_path):
    here = {f: [i for i in request.session.items if i.path == ROOT / f] for f in SERVE_TESTS}
    for f, items in here.items():
        assert [i.nodeid for i in items if "port_8000_held" not in getattr(i, "fixturenames", ())] == [], f
    assert request.getfixturevalue("port_8000_held") is None and port_8000_taken()  # the fixture holds it
    elsewhere = [f for f, items in here.items() if not items]
    if not elsewhere:
        return  # all of them run in this session, port 8000 held
    run = subprocess.run(  # port 8000 held by this process, another one to theirs
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--basetemp", str(tmp_path / "t"), *elsewhere],
        cwd=ROOT, capture_output=True, text=True, timeout=900,
    )
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert re.search(r"^\d+ passed", run.stdout, re.M), run.stdout[-500:]
