"""The session's start compiles every measuring kernel that Python calls (tests/session_start.py): a
kernel its frames do not reach would again be compiled inside the first test that uses it."""

from __future__ import annotations

import pytest

from session_start import WARMED, entry_kernels


def test_the_session_start_reaches_every_measuring_kernel(pytestconfig):
    warmed = pytestconfig.stash.get(WARMED, None)
    if warmed is None:
        pytest.skip("the kernels were compiled by the process that started the session (xdist's controller), not this one")
    kernels = set(entry_kernels())
    assert len(kernels) >= 8, kernels  # measure.kernels' and measure.fit_kernels' entry points, found by type
    assert kernels - warmed.kernels == set(), "kernels the warm-up frames of tests/session_start.py do not run"
    assert warmed.cpu_s > 0 and warmed.wall_s > 0
