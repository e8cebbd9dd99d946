"""The test-time tooling (docs/testing.md, "Where the time goes"): tests/cpu_times.py gives each test the
CPU seconds it cost, with and without pytest-xdist, and tests/durations.py reads them back with the
wall seconds, the run's CPU and its load."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from collections import Counter

from durations import FAST_LOOP, FAST_LOOP_COMMAND, HEAVY_FILE, ROOT, SLOWEST, heavy_tests, heavy_text, parse_log, top_share, what_moves_the_share

LOG = """\
........ [100%]
========================== cpu seconds per test (all) ==========================
2.50s cpu tests/a/test_a.py::test_burn
0.01s cpu tests/a/test_a.py::test_sleep[x y]
session start: 11.6s wall, 11.5s cpu building the measuring kernels (or loading them from the caches), in no test
run: 4.0s wall, 2.5s cpu in tests, 3.1s cpu in this process and its ended children, load 1.5-7.2 (1-minute average, 2 samples, start 1.5, end 7.2); compiled files not written (PYTHONDONTWRITEBYTECODE)
============================== slowest durations ===============================
2.40s call     tests/a/test_a.py::test_burn
0.30s setup    tests/a/test_a.py::test_burn
1.00s call     tests/a/test_a.py::test_sleep[x y]
2 passed in 4.02s
"""


def test_the_log_gives_wall_cpu_load_and_summary():
    run = parse_log(LOG)
    assert run.wall == {"tests/a/test_a.py::test_burn": pytest.approx(2.7), "tests/a/test_a.py::test_sleep[x y]": 1.0}
    assert run.cpu == {"tests/a/test_a.py::test_burn": 2.5, "tests/a/test_a.py::test_sleep[x y]": 0.01}
    assert (run.summary, run.session, run.run_cpu, run.load, run.bytecode) == ("2 passed", 4.02, 3.1, (1.5, 7.2), "not written")
    assert run.start == (11.6, 11.5)
    assert top_share(run.wall) == 1.0


def test_a_log_without_the_plugin_still_reads():
    run = parse_log("1.00s call     tests/t.py::test_x\n1 passed in 1.10s\n")
    assert (dict(run.wall), dict(run.cpu), run.run_cpu, run.load, run.bytecode, run.start) == ({"tests/t.py::test_x": 1.0}, {}, None, None, None, None)


def test_the_share_moves_when_the_slowest_gain_on_the_rest_not_when_all_do():
    # 22 tests of 10 s in tests/slow/, 78 of 1 s in tests/quick/: the slowest 22 are 220 of 298 s
    per_test = Counter({f"tests/slow/test_s.py::test_{i}": 10.0 for i in range(SLOWEST)})
    per_test.update({f"tests/quick/test_q.py::test_{i}": 1.0 for i in range(78)})
    rows = dict(line.strip("| ").split(" | ") for line in what_moves_the_share(per_test) if line.startswith("| ") and "%" in line)
    assert rows["as run"] == f"{220 / 298:.1%}" == rows["every test at half"] == rows["those 2 folders at half"]
    assert rows["`tests/slow/` at half its time"] == rows[f"only the slowest {SLOWEST} at half"] == f"{110 / 188:.1%}"
    assert rows["`tests/quick/` at half its time"] == f"{220 / 259:.1%}"


def test_heavy_tests_are_the_costly_unit_tests_and_their_file_reads_back():
    log = LOG + "0.40s cpu tests/studies/test_s.py::test_study\n3.00s call     tests/studies/test_s.py::test_study\n"
    # test_burn by its CPU, test_sleep[x y] not (1.0 s of wall, 0.01 s of CPU), a study never
    nodes = heavy_tests(parse_log(log))
    assert nodes == ["tests/a/test_a.py::test_burn"]
    text = heavy_text(nodes + ["tests/b/test_b.py::test_wait[1 2]"], "today")
    assert [line for line in text.splitlines() if not line.startswith("#")] == [*nodes, "tests/b/test_b.py::test_wait[1 2]"]


def test_the_heavy_marker_is_given_by_the_listed_node_ids(request):
    listed = {line for line in HEAVY_FILE.read_text().splitlines() if line and not line.startswith("#")}
    assert ("heavy" in request.node.keywords) == (request.node.nodeid in listed)
    assert all("::" in node and node.startswith("tests/") for node in listed)


def test_the_fast_loop_command_selects_the_fast_loop():
    assert FAST_LOOP_COMMAND[-len(FAST_LOOP):] == FAST_LOOP and "-n" in FAST_LOOP_COMMAND


@pytest.mark.slow
@pytest.mark.parametrize("workers", [[], ["-n", "2"]], ids=["in-process", "xdist"])
def test_cpu_seconds_are_the_tests_own_in_and_out_of_xdist(tmp_path, workers):
    # One test spins until it has used 0.3 s of CPU, one sleeps 0.3 s: however busy the machine, the
    # first costs at least 0.3 s of CPU (less the last digit printed) and the second almost none.
    (tmp_path / "conftest.py").write_text(textwrap.dedent("""\
        from cpu_times import CpuTimes

        def pytest_configure(config):
            config.pluginmanager.register(CpuTimes(), "cpu_times")
        """))
    (tmp_path / "test_work.py").write_text(textwrap.dedent("""\
        import time

        def test_spin():
            start = time.process_time()
            while time.process_time() - start < 0.3:
                pass

        def test_sleep():
            time.sleep(0.3)
        """))
    # the installed plugins no test here uses left out, as the project's addopts does (outside the
    # project it does not apply): schemathesis's and hypothesis's imports cost ~4 s of CPU per process
    unused = ["-p", "no:schemathesis", "-p", "no:anyio", "-p", "no:hypothesispytest"]
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *unused, "--durations=0", *workers, str(tmp_path)],
                         cwd=tmp_path, capture_output=True, text=True, check=False,
                         env={"PYTHONPATH": str(ROOT / "tests"), "PATH": "/usr/bin:/bin",
                              # the run line says whether Python writes compiled files: not in one case, in the other
                              **({} if workers else {"PYTHONDONTWRITEBYTECODE": "1"})}).stdout
    run = parse_log(out)
    assert run.summary == "2 passed", out
    assert run.cpu["test_work.py::test_spin"] >= 0.29 and run.cpu["test_work.py::test_sleep"] < 0.1, out
    assert run.wall["test_work.py::test_sleep"] >= 0.3 and run.load is not None and run.run_cpu is not None, out
    assert run.bytecode == ("written" if workers else "not written"), out
