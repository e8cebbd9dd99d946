"""The measurement benchmark and `depthruler bench`: discovery, bad names, and that the sklearn
reference really runs the same pipeline (same answer) so the timing ratio compares like with like."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

import importlib

from cli.bench import discover
from cli.main import app


def _load(name: str):
    return importlib.import_module(discover()[name])


def test_discovers_the_measure_benchmark():
    found = discover()
    assert "measure" in found and found["measure"] == "bench.bench_measure"


def test_the_help_names_every_benchmark():
    out = " ".join(CliRunner().invoke(app, ["bench", "--help"], terminal_width=200).output.split())
    assert all(name in out for name in discover()) and "memory" in discover()


def test_unknown_benchmark_is_a_clear_error():
    result = CliRunner().invoke(app, ["bench", "nope"])
    assert result.exit_code == 2 and "unknown benchmark 'nope'" in result.output


def test_options_need_one_benchmark():
    result = CliRunner().invoke(app, ["bench", "all", "--write"])
    assert result.exit_code == 2 and "need one benchmark name" in result.output


@pytest.mark.parametrize("name", sorted(discover()))
def test_every_benchmark_takes_its_options_from_the_command(name, capsys):
    # `depthruler bench NAME ...` hands the options after NAME to main(argv), never the CLI's own argv.
    with pytest.raises(SystemExit) as exc:
        _load(name).main(["--help"])
    assert exc.value.code == 0
    assert "--write" in capsys.readouterr().out or name == "service_load"


def test_measure_report_judges_each_run_against_both_targets():
    mod = _load("measure")
    row = {"n_samples": 1280, "n_support": 800, "median_ms": 3.0, "p99_ms": 4.0, "cpu_median_ms": 3.0, "cpu_p99_ms": 4.0,
           "sklearn_median_ms": 600.0, "sklearn_cpu_median_ms": 600.0, "speedup": 200.0, "distance_m": 4.5, "sklearn_distance_m": 4.5}
    slow = dict(row, cpu_median_ms=5.5, speedup=110.0)
    text = mod.report([{"robust": row}, {"robust": slow}], (0.5, 0.6), "2026-11-23 12:00 UTC")
    assert "CPU median 3.00-5.50 ms, speed-up 110-200x; both targets met in 1 of 2 runs." in text
    assert text.startswith(mod.SECTION)


@pytest.mark.slow
def test_sklearn_reference_gives_the_same_answer():
    rows = _load("measure").run(repeats=2, ref_repeats=1)
    for method in ("robust", "paper"):
        r = rows[method]
        assert r["n_samples"] == 1280
        assert r["distance_m"] == pytest.approx(r["sklearn_distance_m"], rel=1e-3)


def test_bench_dependencies_are_declared():
    """Every third-party module a bench script imports is a main dependency or in the `bench` extra
    (`depthruler bench measure` crashed on a plain install: No module named 'threadpoolctl')."""
    import ast
    import sys
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    declared = {d.split(">")[0].split("[")[0].strip().lower() for d in project["dependencies"] + project["optional-dependencies"]["bench"]}
    distribution = {"sklearn": "scikit-learn", "cv2": "opencv-contrib-python-headless", "yaml": "pyyaml"}
    ours = {"measure", "device", "sim", "history", "check", "batch", "service", "evaluation", "cli", "bench"}
    needed = set()
    for script in (root / "bench").glob("*.py"):
        for node in ast.walk(ast.parse(script.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 else []
            for name in names:
                top = name.split(".")[0]
                if top not in ours and top not in sys.stdlib_module_names:
                    needed.add(distribution.get(top, top).lower())
    assert needed and needed <= declared, sorted(needed - declared)


def test_missing_bench_dependency_says_how_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "httpx", None)  # as on an install without the bench extra
    monkeypatch.delitem(sys.modules, "bench.bench_service_load", raising=False)  # imported by an earlier test
    result = CliRunner().invoke(app, ["bench", "service_load", "--no-record"])
    assert result.exit_code == 2 and "depthruler[bench]" in result.output and "httpx" in result.output


def test_export_bench_compares_the_same_files(tmp_path):
    # run() raises SystemExit when the streamed and whole exports differ; both read every row
    rows = _load("export").run(n=40, repeats=1)
    assert set(rows) == {"CSV", "JSON"}
    assert rows["JSON"]["total"] > rows["CSV"]["total"] > 40 * 200  # 40 rows of ~250 bytes; the JSON has the arrays


def test_shapes_report_judges_every_run_against_each_target():
    mod = _load("shapes")
    rows = [{"seed": 4, "shape": k, "cpu_median_ms": ms, "cpu_p90_ms": ms, "wall_median_ms": ms, "segment_cpu_ms": 5.0, "ratio": ms / 5}
            for k, ms in (("box", 40.0), ("height", 12.0), ("area", 8.0))]
    text = mod.report([rows], (0.5, 0.6), "2026-12-03 08:00 UTC")
    assert text.startswith(mod.SECTION)
    assert "| 1 | 4 | box | 40.0 / 40.0 | 40.0 | 5.0 | 8.0x | 50 |" in text
    assert text.rstrip().endswith("Targets met in every run: box yes, height no, area yes.")


def test_the_same_work_reference_finds_our_support_and_uses_our_settings():
    """scikit-learn doing our FAST-MCD's work (starts, candidates kept, C-steps) finds nearly the same
    support on lines with 30 % wrong matches, and hands scikit-learn our numbers."""
    from unittest import mock

    from sklearn.covariance import _robust_covariance

    from measure.dline import _BEST_PER_SUBSAMPLE, _FULL_DATA_STEPS, _STARTS
    from measure.mcd import fast_mcd

    ref = _load("measure").sklearn_same_work
    agree = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        t = np.linspace(0, 100, 150)
        d = 20 + 0.05 * t + rng.normal(0, 0.2, t.size)
        bad = rng.random(t.size) < 0.3
        d[bad] *= rng.uniform(0.5, 1.5, bad.sum())
        x = np.c_[t, d]
        kw = dict(seed=seed, n_starts=_STARTS, n_best=_BEST_PER_SUBSAMPLE, max_iter=_FULL_DATA_STEPS)
        agree.append(np.mean(fast_mcd(x, **kw).support == ref(x, **kw).support))
    assert min(agree) >= 0.95 and np.mean(agree) >= 0.98
    with mock.patch.object(_robust_covariance, "select_candidates", wraps=_robust_covariance.select_candidates) as spy:
        ref(x, **kw)
    first, second = (c.kwargs for c in spy.call_args_list)
    assert (first["n_trials"], first["select"], first["n_iter"]) == (_STARTS, _BEST_PER_SUBSAMPLE, 2)
    assert second["select"] == 1 and second["n_iter"] == _FULL_DATA_STEPS and len(second["n_trials"][0]) == _BEST_PER_SUBSAMPLE


def test_the_same_work_reference_nests_subsamples_beyond_600_points_as_ours():
    """On the diagonal (1280 points) our FAST-MCD splits its starts over four subsamples of 300, keeps
    the best of each, refines them on the merged 1200 points and then on all: so does the reference
    (before: scikit-learn's own 500 starts and 10 best per subsample, not our work)."""
    from unittest import mock

    from sklearn.covariance import _robust_covariance

    from measure.dline import _BEST_PER_SUBSAMPLE, _FULL_DATA_STEPS, _STARTS

    rng = np.random.default_rng(0)
    t = np.linspace(0, 1400, 1280)
    x = np.c_[t, 20 + 0.01 * t + rng.normal(0, 0.2, t.size)]
    kw = dict(seed=0, n_starts=_STARTS, n_best=_BEST_PER_SUBSAMPLE, max_iter=_FULL_DATA_STEPS, support_fraction=0.5)
    with mock.patch.object(_robust_covariance, "select_candidates", wraps=_robust_covariance.select_candidates) as spy:
        _load("measure").sklearn_same_work(x, **kw)
    calls = [(len(c.args[0]), c.kwargs) for c in spy.call_args_list]
    assert [n for n, _ in calls] == [300, 300, 300, 300, 1200, 1280]
    assert all(k["n_trials"] == _STARTS // 4 and k["select"] == _BEST_PER_SUBSAMPLE and k["n_iter"] == 2 for _, k in calls[:4])
    assert len(calls[4][1]["n_trials"][0]) == 4 * _BEST_PER_SUBSAMPLE and calls[4][1]["select"] == _BEST_PER_SUBSAMPLE
    assert calls[5][1]["select"] == 1 and calls[5][1]["n_iter"] == _FULL_DATA_STEPS


def test_measure_report_tables_every_baseline_revision():
    mod = _load("measure")
    vs = {"abc1234": {"cpu_median_ms": 6.0, "cpu_p99_ms": 9.0, "ratio": 0.5, "same": 1.0},
          "def5678": {"cpu_median_ms": 2.0, "cpu_p99_ms": 3.0, "ratio": 1.5, "same": 1.0}}
    row = {"n_samples": 1280, "n_support": 800, "median_ms": 3.0, "p99_ms": 4.0, "cpu_median_ms": 3.0, "cpu_p99_ms": 4.0,
           "sklearn_median_ms": 90.0, "sklearn_cpu_median_ms": 90.0, "speedup": 30.0, "distance_m": 4.5, "sklearn_distance_m": 4.5,
           "baselines": vs}
    real = {"cases": 48, "samples_median": 280.0, "samples_range": (120, 600), "cpu_median_ms": 2.0, "cpu_p99_ms": 3.0,
            "sklearn_cpu_median_ms": 60.0, "speedup": 30.0, "same_answer": 0.7,
            "baselines": {k: dict(v, ratio=v["ratio"] / 2) for k, v in vs.items()}}
    text = mod.report([{"robust": row}], (0.5, 0.6), "2026-12-05 12:00 UTC", [{"robust": real}])
    assert "| 1 | diagonal | robust | def5678 | 3.00 / 4.00 | 2.00 / 3.00 | 1.50 | 100 % |" in text
    assert ("our median over the baseline's: abc1234: realistic clicks 0.25-0.25, diagonal 0.50-0.50; "
            "def5678: realistic clicks 0.75-0.75, diagonal 1.50-1.50.") in text


def test_measure_report_states_the_ratio_on_realistic_clicks_beside_the_diagonal():
    mod = _load("measure")
    row = {"n_samples": 1280, "n_support": 800, "median_ms": 3.0, "p99_ms": 4.0, "cpu_median_ms": 3.0, "cpu_p99_ms": 4.0,
           "sklearn_median_ms": 390.0, "sklearn_cpu_median_ms": 390.0, "speedup": 130.0, "distance_m": 4.5, "sklearn_distance_m": 4.5}
    real = {"cases": 48, "samples_median": 280.0, "samples_range": (120, 600), "cpu_median_ms": 5.8, "cpu_p99_ms": 11.0,
            "sklearn_cpu_median_ms": 88.0, "speedup": 15.2, "same_answer": 0.67}
    text = mod.report([{"robust": row}], (0.5, 0.6), "2026-12-03 12:00 UTC", [{"robust": real}])
    assert "| 1 | robust | 48 | 280 (120-600) | 5.80 / 11.00 | 88.0 | 15.2x | 67 % |" in text
    assert "15.2-15.2x on realistic clicks, 130-130x on the diagonal" in text
