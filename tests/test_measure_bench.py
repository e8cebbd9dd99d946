"""The measurement benchmark and `depthruler bench`: discovery, bad names, and that the sklearn
reference really runs the same pipeline (same answer) so the timing ratio compares like with like."""

from __future__ import annotations

import importlib.util

import pytest
import typer

from service.bench_cli import bench, discover


def test_discovers_the_measure_benchmark():
    found = discover()
    assert "measure" in found and found["measure"].name == "bench_measure.py"


def test_unknown_benchmark_is_a_clear_error():
    with pytest.raises(typer.BadParameter, match="unknown benchmark 'nope'"):
        bench("nope")


@pytest.mark.slow
def test_sklearn_reference_gives_the_same_answer():
    spec = importlib.util.spec_from_file_location("bench_measure_under_test", discover()["measure"])
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = mod.run(repeats=2, ref_repeats=1)
    for method in ("robust", "paper"):
        r = rows[method]
        assert r["n_samples"] == 1280
        assert r["distance_m"] == pytest.approx(r["sklearn_distance_m"], rel=1e-3)
        assert r["speedup"] > 1.0
