"""Shared fixtures, the folder markers (docs/testing.md), the `hardware` / `browser` skips and the kernels compiled at the session's start."""

from __future__ import annotations

import errno
import gc
import os
import shutil
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from cpu_times import CpuTimes
from server_process import port_8000_taken
from session_start import WARMED, compile_measuring_kernels

# Property-based tests (tests/fuzz/): a small, reproducible budget in the default run; a nightly-style
# exploration with `--hypothesis-profile=long` (README "Fuzzing"; DEPTHRULER_FUZZ_EXAMPLES sets its examples per test). No example database: the tree stays
# clean, and a failure prints the example and `@reproduce_failure` blob to replay it.
settings.register_profile(
    "default", max_examples=40, deadline=None, derandomize=True, database=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "long", max_examples=int(os.environ.get("DEPTHRULER_FUZZ_EXAMPLES", "20000")), deadline=None, database=None, print_blob=True,
    derandomize=False,  # explicit: a profile inherits unset settings from the one loaded when it is registered
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("default")

CHROMIUM = "/usr/bin/chromium"
TESTS = Path(__file__).resolve().parent
# A test in one of these folders carries its marker, so `-m` selects across folders (the fast loop
# leaves them out; docs/testing.md).
FOLDER_MARKERS = {"integration": "integration", "studies": "study", "browser": "browser"}
# The unit tests that cost the most in the last measured full run (tests/heavy.txt, written by
# `tests/durations.py --heavy`): marked `heavy`, which the fast loop leaves out and the full suite runs.
HEAVY = frozenset(line for line in (TESTS / "heavy.txt").read_text().splitlines() if line and not line.startswith("#"))


def pytest_configure(config: pytest.Config) -> None:
    # With --durations, each test's CPU seconds and the host's load as well (tests/cpu_times.py).
    if config.getoption("durations", None) is not None:
        config.pluginmanager.register(CpuTimes(), "cpu_times")


def pytest_sessionstart(session: pytest.Session) -> None:
    # Compiled once here, not by the first test that measures nor by each xdist worker at once (they
    # start after this hook and load numba's cache); its seconds are printed beside the tests' own.
    config = session.config
    if hasattr(config, "workerinput") or config.getoption("collectonly"):
        return
    try:
        warmed = compile_measuring_kernels()
    except Exception as exc:  # a broken measurement is the tests' to report, one by one
        print(f"session start: measuring the warm-up frames failed ({exc!r}); the tests that measure compile the kernels")
        return
    config.stash[WARMED] = warmed
    timer = config.pluginmanager.get_plugin("cpu_times")
    if timer is not None:
        timer.session_start = (warmed.wall_s, warmed.cpu_s)


def pytest_collection_finish(session: pytest.Session) -> None:
    # The imports and the collected tests live as long as the run: frozen, the collector's full passes
    # no longer walk them, and each app a test starts finds the view frozen and skips its own full
    # pass (service/app.py), which cost 0.1-0.3 s of CPU per app in a process this size.
    gc.collect()
    gc.freeze()


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by marker
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    hardware = os.environ.get("DEPTHRULER_HARDWARE") == "1"
    skip_hw = pytest.mark.skip(reason="needs a camera: set DEPTHRULER_HARDWARE=1 with a device attached")
    has_chromium = shutil.which(CHROMIUM) is not None or Path(CHROMIUM).exists()
    skip_browser = pytest.mark.skip(reason="needs Debian's chromium at /usr/bin/chromium (apt-get install chromium)")
    # The long fuzzing profile runs each property for many minutes: pytest-timeout's 600 s per test would cut it.
    long_fuzz = config.getoption("hypothesis_profile", default=None) == "long"
    for item in items:
        folder = item.path.relative_to(TESTS).parts[0] if item.path.is_relative_to(TESTS) else ""
        if folder in FOLDER_MARKERS:
            item.add_marker(FOLDER_MARKERS[folder])
        if item.nodeid in HEAVY:
            item.add_marker("heavy")
        if long_fuzz and "fuzz" in item.nodeid.split("/"):
            item.add_marker(pytest.mark.timeout(0))
        if "hardware" in item.keywords and not hardware:
            item.add_marker(skip_hw)
        if "browser" in item.keywords and not has_chromium:
            item.add_marker(skip_browser)


@pytest.fixture(scope="session")
def middlebury_dir() -> Path:
    """The Middlebury scenes' folder; the tests that need it skip, naming the fetch command, without it.
    Imported here, not at the top: a run of the unit folders does not load ``evaluation``."""
    from evaluation.middlebury_data import FETCH_COMMAND, default_data_dir

    root = default_data_dir()
    if not (root / "Adirondack" / "im0.png").is_file():
        pytest.skip(f"the Middlebury scenes are not at {root}: fetch them with `{FETCH_COMMAND}` "
                    "(or set DEPTHRULER_SHARED to a folder that holds data/middlebury)")
    return root


@pytest.fixture(scope="module")
def port_8000_held() -> Iterator[None]:
    """Port 8000 held on every IPv4 address while a module's tests run: the modules that run or
    configure ``serve`` use it, so the suite shows they do not depend on the default port
    (tests/integration/test_busy_default_port.py checks that they do). Held already by another
    program is the case under test too."""
    holder = socket.socket()
    try:
        holder.bind(("0.0.0.0", 8000))
        holder.listen()
    except OSError as exc:
        holder.close()
        if exc.errno != errno.EADDRINUSE:
            raise
    try:
        assert port_8000_taken(), "could not hold port 8000"
        yield
    finally:
        holder.close()
