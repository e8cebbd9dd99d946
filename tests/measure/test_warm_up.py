"""``measure.warm_up`` loads every compiled kernel a measurement uses: after it, measuring simulated
scenes (segments short and long, a gap, a person) and a box, a height and an area on a simulated box
loads no kernel it did not (else a person's first such click pays for loading it, or for compiling it
after an install). With numba's kernels: no new version compiled or loaded; with the kernels built
ahead of time (whose build exports what the warm-up compiles): no call without its built version,
and numba never imported."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from build_tools import missing_build_tools

ROOT = Path(__file__).resolve().parents[2]

# Run in a fresh interpreter: this test process has loaded every kernel already (tests/session_start.py).
SCRIPT = """
import importlib, json, pkgutil, sys
import numpy as np
import measure

def loaded():
    if "numba" not in sys.modules:
        return {}
    from numba.core.registry import CPUDispatcher
    out = {}
    for info in pkgutil.iter_modules(measure.__path__):
        module = importlib.import_module("measure." + info.name)
        for name, value in vars(module).items():
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == module.__name__:
                out[module.__name__ + "." + name] = len(value.signatures)
    return out

origin = measure.warm_up().split(":")[0]
before = loaded()
from measure import MeasureOptions, measure_area, measure_box, measure_distance, measure_height
from measure.options import METHODS
from sim.scenario import scenario
from sim.shapes import box_case
for scene, distance in (("poster", 3.0), ("poster", 7.0), ("doorway", 2.0), ("person", 5.0)):
    frame, _, clicks = scenario(scene, distance_m=distance, seed=3)[:3]
    for method in METHODS:
        measure_distance(frame, *clicks, MeasureOptions(method=method))
        measure_distance(frame, (20.0, 300.0), (1260.0, 420.0), MeasureOptions(method=method))  # over 600 samples
case = box_case(4, "stress", range_m=None, variant="plain", width=640, height=360)
corners = np.array(case.corners_px)
centre = corners.mean(axis=0)
measure_box(case.frame, case.click_px)
measure_height(case.frame, case.click_px)
measure_area(case.frame, [tuple(centre + 0.7 * (c - centre)) for c in corners])
after = loaded()
print(json.dumps({"origin": origin, "numba": "numba" in sys.modules, "fallbacks": measure.compiled.active().fallbacks,
                  "loaded_later": {k: [before.get(k, 0), n] for k, n in after.items() if before.get(k, 0) != n}}))
"""


@pytest.mark.parametrize("mode", ["jit", "auto"])
def test_after_the_warm_up_no_measurement_loads_a_kernel(mode):
    env = {**os.environ, "DEPTHRULER_KERNELS": mode, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["loaded_later"] == {}, f"kernels (signatures before -> after) measure.warm_up does not reach: {got['loaded_later']}"
    if mode == "auto" and not missing_build_tools():  # the session start built the module (tests/measure/test_aot.py holds its answers)
        assert got["origin"] == "aot" and got["fallbacks"] == {} and not got["numba"], got
