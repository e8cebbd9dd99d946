"""The kernels built ahead of time (measure.aot, measure.compiled): the same answers as numba's
just-in-time kernels bit for bit, a measuring process without numba or LLVM, every call checked
against the types the module was built for, and numba's kernels kept when the build cannot run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from build_tools import missing_build_tools
from measure import aot, compiled

ROOT = Path(__file__).resolve().parents[2]

# Measured in a fresh interpreter: every method on simulated scenes (short and long segments, a gap,
# a person, far away) and a box and a height; prints the answers, where the kernels came from, the
# calls the built module had no version for, and whether numba was ever imported.
SCRIPT = """
import dataclasses, json, sys
import measure
origin = measure.warm_up()
from measure import MeasureError, MeasureOptions, measure_box, measure_distance, measure_height, compiled
from measure.options import METHODS
from sim.scenario import scenario
from sim.shapes import box_case
out = []
for scene, distance, seed in (("poster", 3.0, 3), ("poster", 7.0, 1), ("doorway", 2.0, 2), ("person", 5.0, 4)):
    frame, _, clicks = scenario(scene, distance_m=distance, seed=seed, width=640, height=360)[:3]
    for method in METHODS:
        for c in (clicks, ((10.0, 150.0), (630.0, 210.0))):
            try:
                m = measure_distance(frame, *c, MeasureOptions(method=method))
                out.append([m.distance_m, m.uncertainty_m, m.quality, list(m.p1_m), list(m.p2_m), m.fit])
            except MeasureError as exc:
                out.append(str(exc))
case = box_case(4, "stress", range_m=None, variant="plain", width=640, height=360)
for fn in (measure_box, measure_height):
    try:
        answer = dataclasses.asdict(fn(case.frame, case.click_px))
        out.append(repr({k: v for k, v in answer.items() if k != "elapsed_ms"}))
    except MeasureError as exc:
        out.append(str(exc))
print(json.dumps({"origin": origin.split(":")[0], "fallbacks": compiled.active().fallbacks,
                  "numba": "numba" in sys.modules or "llvmlite" in sys.modules, "out": out}))
"""


def _env(**extra: str) -> dict[str, str]:
    """This process's environment, with this checkout first on the path and ``extra`` set."""
    return {**os.environ, **extra, "PYTHONPATH": os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)}


def _run(mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=_env(DEPTHRULER_KERNELS=mode), capture_output=True,
                          text=True, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def built() -> Path:
    """The module built for this checkout and machine (the session start built it, else this does)."""
    if missing := missing_build_tools():
        pytest.skip(missing)
    if aot.find_built() is None and aot.prepare().startswith("jit"):
        pytest.fail(f"the kernels could not be built ahead of time here: {aot.LAST_ERROR}")
    folder = aot.find_built()
    assert folder is not None
    return folder


def test_built_kernels_answer_as_numbas_bit_for_bit_without_loading_numba(built):
    jit, ahead = _run("jit"), _run("auto")
    assert (jit["origin"], ahead["origin"]) == ("jit", "aot")
    assert ahead["out"] == jit["out"] and len(ahead["out"]) == 4 * 3 * 2 + 2
    assert sum(isinstance(a, list) for a in ahead["out"]) >= 20  # answers, not only refusals
    assert ahead["fallbacks"] == {}  # every call had its version in the module
    assert not ahead["numba"] and jit["numba"]  # neither numba nor LLVM in the measuring process


def test_a_call_the_module_was_not_built_for_goes_to_numba(built, monkeypatch):
    kernels = compiled.load_aot(built)
    monkeypatch.setattr(compiled, "_active", kernels)
    x = np.arange(41.0)
    assert compiled.median_1d(x) == 20.0 and kernels.fallbacks == {}
    # strided, single precision, integers, two dimensions: the built function would read them as contiguous
    # float64 vectors (a wrong answer or a crash); each goes to numba's kernel, which compiles for it
    assert compiled.median_1d(np.arange(82.0)[::2]) == 40.0
    assert compiled.median_1d(x.astype(np.float32)) == 20.0
    assert kernels.fallbacks == {"median_1d": 2}


def test_the_argument_check_takes_exactly_the_built_types():
    check = compiled.make_check([
        {"kind": "array", "dtype": "float64", "ndim": 2, "layout": "C", "readonly": False},
        {"kind": "array", "dtype": "int64", "ndim": 1, "layout": "A", "readonly": True},
        {"kind": "scalar", "type": "float64"},
        {"kind": "scalar", "type": "int64"},
        {"kind": "scalar", "type": "bool"},
    ])
    a, b = np.zeros((3, 4)), np.arange(6)[::2]
    frozen = a.copy()
    frozen.setflags(write=False)
    assert check(a, b, 1.5, 3, True) and check(a, b, np.float64(1.5), np.int64(3), np.bool_(False))
    assert not check(a.T, b, 1.5, 3, True)  # not C order
    assert not check(frozen, b, 1.5, 3, True)  # the kernel may write it
    assert not check(a.astype(np.float32), b, 1.5, 3, True) and not check(a[0], b, 1.5, 3, True)
    assert not check(a, b.astype(np.int32), 1.5, 3, True)
    assert not check(a, b, 1, 3, True) and not check(a, b, np.float32(1.5), 3, True)  # numba types these otherwise
    assert not check(a, b, 1.5, True, True) and not check(a, b, 1.5, 3.0, True) and not check(a, b, 1.5, 3, 1)
    assert compiled.make_check([{"kind": "scalar", "type": "complex128"}])(1j) is False  # unknown: never built


def test_a_build_that_cannot_run_keeps_numbas_kernels(tmp_path):
    """No C compiler (CC fails): the process measures with numba's kernels and says why."""
    env = _env(DEPTHRULER_CACHE_DIR=str(tmp_path), CC="/bin/false", DEPTHRULER_KERNELS="auto")
    script = "import measure; from measure import aot; print(measure.warm_up()); print(aot.LAST_ERROR)"
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    origin, error = done.stdout.strip().splitlines()[-2:]
    assert origin.startswith("jit: building the kernels ahead of time failed") and origin == f"jit: {error}"
    assert not any((tmp_path / "aot").glob("*/manifest.json"))  # nothing half-built is published
    env["DEPTHRULER_KERNELS"] = "aot"  # asked for explicitly, the same failure is an error
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode != 0 and "DEPTHRULER_KERNELS=aot" in done.stderr


def test_the_cache_key_follows_the_sources(tmp_path, monkeypatch):
    before = aot.key()
    copy = tmp_path / "measure"
    copy.mkdir()
    for path in aot.PACKAGE.glob("*.py"):
        (copy / path.name).write_bytes(path.read_bytes())
    monkeypatch.setattr(aot, "PACKAGE", copy)
    assert aot.key() == before
    (copy / "robust.py").write_text((copy / "robust.py").read_text() + "\n# changed\n")
    assert aot.key() != before


def test_old_builds_are_removed_but_the_newest(tmp_path):
    folders = []
    for i in range(7):
        folder = tmp_path / f"build{i}"
        folder.mkdir()
        (folder / compiled.MANIFEST).write_text("{}")
        os.utime(folder, (1000 + i, 1000 + i))
        folders.append(folder)
    (tmp_path / "build2.tmp").mkdir()  # an unfinished build (no manifest) is another process's: left alone
    aot._prune(folders[0])  # the one just built, whatever its time
    assert sorted(p.name for p in tmp_path.iterdir()) == ["build0", "build2.tmp", "build4", "build5", "build6"]


def test_built_kernels_release_the_interpreters_lock(built):
    """The service measures on two threads beside its event loop: a built kernel's wrapper releases
    the interpreter's lock around the call, as numba's ``nogil`` kernels do. (A count of another
    thread's steps during a call does not tell the two apart reliably: the hand-over of the lock
    before the call takes as long as a short kernel.)"""
    manifest = json.loads((built / compiled.MANIFEST).read_text())
    assert b"PyEval_SaveThread" in (built / manifest["file"]).read_bytes()
