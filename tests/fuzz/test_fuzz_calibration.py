"""Fuzzing stereo calibration files: JSON with fields replaced, removed or added, and
files mutated byte by byte.

Every file either loads or raises CalibrationError naming the file; never another exception or a
warning (but the CalibrationWarning, naming the file, with which an R a little off a rotation is repaired). A calibration that loads can be used: rectifying images of its size gives a camera and
baseline in their physical ranges, or a CalibrationError saying what to fix.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
from hypothesis import event, given
from hypothesis import strategies as st

from device.calibration.stereo import CalibrationWarning, StereoCalibration, load_calibration
from device.errors import CalibrationError
from device.sources.stereo_processing import rectification
from fuzzing import EDGE_FLOATS, ODD_TEXT, allowing, finite, typed_or_answer

K_LEFT = np.array([[1000.0, 0, 640.5], [0, 1002.0, 359.5], [0, 0, 1]])
K_RIGHT = np.array([[995.0, 0, 630.25], [0, 997.0, 362.75], [0, 0, 1]])
R_LR, _ = cv2.Rodrigues(np.array([0.002, -0.015, 0.004]))
T_LR = np.array([-0.06, 0.0004, 0.0008])
BASE = StereoCalibration(
    image_size=(1280, 720), K1=K_LEFT, D1=np.array([0.05, -0.1, 0.001, 0.0, 0.02]), K2=K_RIGHT,
    D2=np.zeros(5), R=R_LR, T=T_LR, rms=0.3, created="2026-12-01T00:00:00+00:00",
).to_json()
FIELDS = sorted(BASE)

JSON_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), EDGE_FLOATS.filter(math.isfinite), ODD_TEXT,
    st.sampled_from([0, 1, -1, 1e-12, 1e12, 1e308, "1", "nan", "Infinity"]),
)
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(ODD_TEXT, inner, max_size=3)), max_leaves=12)


@st.composite
def near_field(draw: st.DrawFn, name: str) -> object:
    """The field's own value, perturbed: one number changed, a row dropped, a scale applied."""
    value = json.loads(json.dumps(BASE[name]))
    if isinstance(value, list) and value:
        flat = np.asarray(value, dtype=float) if all(isinstance(v, (int, float, list)) for v in value) else None
        if flat is not None and flat.dtype == float:
            op = draw(st.integers(0, 3))
            if op == 0:
                idx = draw(st.integers(0, flat.size - 1))
                flat.flat[idx] = draw(st.one_of(EDGE_FLOATS.filter(math.isfinite), st.floats(-2000, 2000)))
            elif op == 1:
                flat = flat * draw(st.sampled_from([0.0, -1.0, 1e-3, 1e3, 1e9, 1e-9]))
            elif op == 2:
                flat = flat[: draw(st.integers(0, max(0, len(flat) - 1)))]
            else:
                flat = np.concatenate([flat.ravel(), [0.0]])
            return flat.tolist()
    return draw(JSON_VALUES)


@st.composite
def documents(draw: st.DrawFn) -> bytes:
    doc = json.loads(json.dumps(BASE))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.integers(0, 9))
        name = draw(st.sampled_from(FIELDS))
        if op <= 5:
            doc[name] = draw(near_field(name))
        elif op <= 7:
            doc[name] = draw(JSON_VALUES)
        elif op == 8:
            doc.pop(name, None)
        else:
            doc[draw(ODD_TEXT)] = draw(JSON_VALUES)
    if draw(st.integers(0, 19)) == 0:
        doc = draw(JSON_VALUES)
    return json.dumps(doc, ensure_ascii=draw(st.booleans())).encode("utf-8", "surrogatepass")


@st.composite
def mutated_bytes(draw: st.DrawFn) -> bytes:
    data = bytearray(json.dumps(BASE, indent=2).encode())
    for _ in range(draw(st.integers(1, 5))):
        i = draw(st.integers(0, len(data) - 1))
        op = draw(st.integers(0, 2))
        if op == 0:
            data[i] = draw(st.integers(0, 255))
        elif op == 1:
            del data[i : i + draw(st.integers(1, 6))]
        else:
            data[i:i] = draw(st.sampled_from([b"\xff", b"\x00", b"-", b"9", b"e99", b"[", b"}", b"NaN", b",", b'"']))
    return bytes(data)


def _check(path) -> None:
    # an R a little off a rotation loads with a CalibrationWarning naming the file (documented repair)
    load = allowing(CalibrationWarning, lambda: load_calibration(path), (str(path),))
    calib = typed_or_answer(load, CalibrationError)
    if calib is None:
        try:
            load()
        except CalibrationError as exc:
            assert str(path) in str(exc), f"the message does not name the file: {exc}"
        event("rejected")
        return
    event("loaded")
    w, h = calib.image_size
    assert w >= 1 and h >= 1
    assert 0 < calib.baseline_m <= 5
    if w * h > 1280 * 720:
        return  # the maps would cost more than a fuzz example should
    rect = typed_or_answer(lambda: rectification(calib, (w, h)), CalibrationError)
    event("rectified" if rect is not None else "rectification rejected")
    if rect is not None:
        assert finite(rect.baseline_m) and rect.baseline_m > 0 and finite(rect.doffs)


@given(documents())
def test_calibration_documents_load_or_name_the_file(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("calib") / "pair.json"
    path.write_bytes(data)
    _check(path)


@given(mutated_bytes())
def test_calibration_files_mutated_byte_by_byte(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("calib") / "pair.json"
    path.write_bytes(data)
    _check(path)
