"""The session's start compiled the measuring kernels (tests/session_start.py), so no test carries
the compile; what it reaches is held by tests/measure/test_warm_up.py."""

from __future__ import annotations

import pytest

from session_start import WARMED


def test_the_session_start_warmed_the_kernels(pytestconfig):
    if hasattr(pytestconfig, "workerinput"):
        pytest.skip("the kernels were compiled by the process that started the session (xdist's controller), not this one")
    warmed = pytestconfig.stash.get(WARMED, None)
    assert warmed is not None, "the session start's measure.warm_up() failed: its message is at the top of the run"
    assert warmed.cpu_s > 0 and warmed.wall_s > 0
