"""Fuzzing every calibration file reader: OpenCV FileStorage YAML and XML, ROS camera_info pairs and the
project's JSON, mutated byte by byte from valid files, plus the hostile cases found by hand (garbage, an
empty file, a video given as calib=, impossible numbers, matrices whose rows do not match their data,
deep nesting, long lists, a matrix claiming 10^8 rows).

Every file either loads or raises CalibrationError naming the file; never another exception or a warning
(but the CalibrationWarning naming the file with which an R a little off a rotation is repaired),
and each read ends within a second (a per-call alarm, which also stops a quadratic parse or a huge
allocation in Python code; OpenCV's own parser is bounded by the size and nesting checks that come first).
"""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from device.calibration.files import UNITS, CalibrationRef, write
from device.calibration.stereo import DISTORTION_MODELS, CalibrationWarning, StereoCalibration, load_calibration
from device.errors import CalibrationError
from fuzzing import allowing, byte_edits, typed_or_answer

R_LR, _ = cv2.Rodrigues(np.array([0.002, -0.015, 0.004]))
CALIB = StereoCalibration(
    image_size=(1280, 720), K1=np.array([[1000.0, 0, 640.5], [0, 1002.0, 359.5], [0, 0, 1]]),
    D1=np.array([0.05, -0.1, 0.001, 0.0, 0.02]), K2=np.array([[995.0, 0, 630.25], [0, 997.0, 362.75], [0, 0, 1]]),
    D2=np.zeros(5), R=R_LR, T=np.array([-0.06, 0.0004, 0.0008]), rms=0.3, created="2026-12-01T00:00:00+00:00",
)
TOKENS = (b"\xff", b"\x00", b"-", b"9", b"e999", b"[", b"]", b"{", b"}", b".nan", b".inf", b"abc", b":", b",",
          b'"', b"'", b"\n  ", b"!!opencv-matrix", b"rows: 100000000", b"<", b"</", b">", b"&amp;", b"%YAML:1.0\n")
SECOND = 1.0  # each read must end within this
# The reader's options as a source spec gives them (calib_units, calib_square_mm, distortion): each takes
# another path after the parse (a unit conversion, the squares' side, a lens model replaced).
OPTIONS = st.fixed_dictionaries({}, optional={
    "units": st.sampled_from(sorted(UNITS)), "square_mm": st.sampled_from([25.0, 1e-9, 1e9]),
    "distortion_model": st.sampled_from(DISTORTION_MODELS),
})
SPEC_OPTIONS = ({}, {"units": "mm", "distortion_model": "equidistant"}, {"units": "squares", "square_mm": 25.0})


class TooSlow(Exception):
    pass


@contextmanager
def within(seconds: float) -> Iterator[None]:
    """Raise TooSlow in this thread when the block runs longer than ``seconds``."""
    def alarm(signum, frame):
        raise TooSlow(f"a calibration read took more than {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def read(ref: str, options: dict | None = None) -> None:
    """Load ``ref`` (with the spec's ``options``) through every reader that takes it; only CalibrationError,
    naming a file, may come out."""
    # an R a little off a rotation is repaired with a CalibrationWarning naming the file, as documented
    names = tuple(ref.split(","))
    readers = [allowing(CalibrationWarning, lambda: CalibrationRef(ref, **(options or {})).load(), names)]
    if ref.endswith(".json"):
        readers.append(allowing(CalibrationWarning, lambda: load_calibration(ref), names))
    for reader in readers:
        with within(SECOND):
            calib = typed_or_answer(reader, CalibrationError)
        if calib is None:
            try:
                reader()
            except CalibrationError as exc:
                assert any(p in str(exc) for p in ref.split(",")), f"the message does not name the file: {exc}"
            event("rejected")
        else:
            event("loaded")
            assert calib.image_size[0] >= 1 and 0 < calib.baseline_m <= 5


def valid_files(folder: Path) -> dict[str, list[Path]]:
    return {fmt: write(CALIB, folder / f"c.{ext}", fmt)
            for fmt, ext in (("opencv-yaml", "yaml"), ("opencv-xml", "xml"), ("ros", "yaml"), ("json", "json"))}


@pytest.fixture(scope="module")
def originals(tmp_path_factory) -> dict[str, list[bytes]]:
    files = valid_files(tmp_path_factory.mktemp("valid"))
    return {fmt: [p.read_bytes() for p in paths] for fmt, paths in files.items()}


@pytest.mark.parametrize("fmt", ["opencv-yaml", "opencv-xml", "ros", "json"])
@given(data=st.data())
def test_mutated_calibration_files_load_or_raise_calibration_error(originals, tmp_path_factory, fmt, data):
    folder = tmp_path_factory.mktemp("mut")
    docs = originals[fmt]
    hit = data.draw(st.integers(0, len(docs) - 1))
    suffix = {"opencv-xml": ".xml", "json": ".json"}.get(fmt, ".yaml")
    paths = []
    for k, doc in enumerate(docs):
        p = folder / f"c{k}{suffix}"
        p.write_bytes(data.draw(byte_edits(doc, TOKENS, edits=6, cut=40, repeat=True)) if k == hit else doc)
        paths.append(p)
    read(",".join(map(str, paths)), data.draw(OPTIONS))


def opencv_yaml(**fields: str) -> str:
    base = {"image_width": "1280", "image_height": "720",
            "K1": "!!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [1000., 0., 640.5, 0., 1002., 359.5, 0., 0., 1.]",
            "D1": "[0.05, -0.1, 0.001, 0., 0.02]", "K2": "[[995., 0., 630.25], [0., 997., 362.75], [0., 0., 1.]]",
            "D2": "[0., 0., 0., 0., 0.]", "R": "[0.002, -0.015, 0.004]", "T": "[-0.06, 0.0004, 0.0008]"}
    base.update(fields)
    return "%YAML:1.0\n---\n" + "".join(f"{k}: {v}\n" for k, v in base.items())


def ros_yaml(side: str, **fields: str) -> str:
    tx = "0." if side == "left" else "-59.7"
    base = {"image_width": "1280", "image_height": "720", "camera_name": side,
            "camera_matrix": "\n  rows: 3\n  cols: 3\n  data: [995., 0., 640., 0., 995., 360., 0., 0., 1.]",
            "distortion_model": "plumb_bob", "distortion_coefficients": "\n  rows: 1\n  cols: 5\n  data: [0., 0., 0., 0., 0.]",
            "rectification_matrix": "\n  rows: 3\n  cols: 3\n  data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]",
            "projection_matrix": f"\n  rows: 3\n  cols: 4\n  data: [995., 0., 640., {tx}, 0., 995., 360., 0., 0., 0., 1., 0.]"}
    base.update(fields)
    return "".join(f"{k}: {v}\n" for k, v in base.items())


def nested(depth: int) -> str:
    return "[" * depth + "1" + "]" * depth


CASES = {
    "garbage": [b"\x8f\x01 :: [[ {{ !!opencv-matrix %% \xfe"],
    "empty": [b""],
    "blank": [b"   \n\n"],
    "video": [b"RIFF\x00\x10\x00\x00AVI LIST" + bytes(range(256)) * 8],
    "yaml-list-top": [b"- 1\n- 2\n"],
    "width-1e400": [opencv_yaml(image_width="1e400").encode()],
    "width-nan": [opencv_yaml(image_width=".nan").encode()],
    "width-abc": [opencv_yaml(image_width="abc").encode()],
    "width-negative": [opencv_yaml(image_width="-1280").encode()],
    "width-fraction": [opencv_yaml(image_width="1280.5").encode()],
    "rows-mismatch": [opencv_yaml(K1="!!opencv-matrix\n   rows: 4\n   cols: 3\n   dt: d\n   data: [1., 0., 640.5, 0., 1., 359.5, 0., 0., 1.]").encode()],
    "rows-1e8": [opencv_yaml(K1="!!opencv-matrix\n   rows: 100000000\n   cols: 100000000\n   dt: d\n   data: [1., 2.]").encode()],
    "rows-text": [opencv_yaml(K1="!!opencv-matrix\n   rows: three\n   cols: 3\n   dt: d\n   data: [1., 2., 3.]").encode()],
    "ragged-rows": [opencv_yaml(K2="[[995., 0.], [0., 997., 362.75], [0., 0., 1.]]").encode()],
    "matrix-text": [opencv_yaml(D1='["a", "b", "c", "d", "e"]').encode()],
    "matrix-nested": [opencv_yaml(T="[[[-0.06]], [[0.]], [[0.]]]").encode()],
    "R-wrong-size": [opencv_yaml(R="[1., 0., 0., 0.]").encode()],
    "deep-flow": [opencv_yaml(T=nested(100_000)).encode()],
    "deep-block": [("%YAML:1.0\n---\n" + "".join(" " * k + f"a{k}:\n" for k in range(0, 4000, 2)) + " " * 4000 + "x: 1\n").encode()],
    "long-list-20k": [opencv_yaml(D1="[" + ", ".join("0.5" for _ in range(20_000)) + "]").encode()],
    "long-list-200k": [opencv_yaml(D1="[" + ",".join("1" for _ in range(200_000)) + "]").encode()],
    "many-keys": [("%YAML:1.0\n---\n" + "".join(f"k{k}: {k}\n" for k in range(50_000))).encode()],
    "xml-entities": [b'<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">]>'
                     b"<opencv_storage><T>&b;&b;&b;</T></opencv_storage>"],
    "xml-deep": [b'<?xml version="1.0"?><opencv_storage>' + b"<a>" * 5000 + b"1" + b"</a>" * 5000 + b"</opencv_storage>"],
    "xml-broken": [b'<?xml version="1.0"?><opencv_storage><K1 type_id="opencv-matrix"><rows>3</rows>'],
    "ros-rows-7": [ros_yaml("left", camera_matrix="\n  rows: 7\n  cols: 3\n  data: [995., 0., 640., 0., 995., 360., 0., 0., 1.]").encode(),
                   ros_yaml("right").encode()],
    "ros-text-data": [ros_yaml("left", distortion_coefficients="\n  rows: 1\n  cols: 5\n  data: [a, b, c, d, e]").encode(),
                      ros_yaml("right").encode()],
    "ros-zero-fx": [ros_yaml("left").encode(),
                    ros_yaml("right", projection_matrix="\n  rows: 3\n  cols: 4\n  data: [0., 0., 640., -59.7, 0., 995., 360., 0., 0., 0., 1., 0.]").encode()],
    "ros-short-P": [ros_yaml("left").encode(), ros_yaml("right", projection_matrix="[995., 0., 640., -59.7]").encode()],
    "ros-huge-cols": [ros_yaml("left", camera_matrix="\n  rows: 1\n  cols: 100000000\n  data: [1.]").encode(), ros_yaml("right").encode()],
    "json-huge": [b'{"K1": [' + b"1," * 600_000 + b"1]}"],
    "json-deep": [b"[" * 100_000 + b"]" * 100_000],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_hostile_calibration_files_raise_calibration_error(tmp_path: Path, case: str) -> None:
    docs = CASES[case]
    suffix = ".json" if case.startswith("json") else ".xml" if case.startswith("xml") else ".avi" if case == "video" else ".yaml"
    paths = []
    for k, doc in enumerate(docs):
        p = tmp_path / f"{case}{k}{suffix}"
        p.write_bytes(doc)
        paths.append(p)
    ref = ",".join(map(str, paths))
    for options in SPEC_OPTIONS:
        with within(SECOND):
            with pytest.raises(CalibrationError) as err:
                CalibrationRef(ref, **options).load()
        assert any(str(p) in str(err.value) for p in paths), (options, err.value)
    if suffix == ".json":
        with within(SECOND), pytest.raises(CalibrationError):
            load_calibration(paths[0])


def test_the_valid_files_still_load(tmp_path: Path) -> None:
    """The bounds refuse nothing a real calibration holds: every format written here reads back equal."""
    for fmt, paths in valid_files(tmp_path).items():
        got = CalibrationRef(",".join(map(str, paths))).load()
        assert got.image_size == CALIB.image_size and np.allclose(got.T, CALIB.T, atol=1e-9), fmt
        assert np.allclose(got.K1, CALIB.K1) and np.allclose(got.D1, CALIB.D1), fmt
    for name, text in (("ocv.yaml", opencv_yaml()),):
        (tmp_path / name).write_text(text)
        assert CalibrationRef(str(tmp_path / name)).load().image_size == (1280, 720)
    (tmp_path / "l.yaml").write_text(ros_yaml("left"))
    (tmp_path / "r.yaml").write_text(ros_yaml("right"))
    assert CalibrationRef(f"{tmp_path / 'l.yaml'},{tmp_path / 'r.yaml'}").load().baseline_m == pytest.approx(0.06)


def test_serve_stops_on_an_unreadable_calibration_instead_of_retrying(tmp_path: Path) -> None:
    """A video source whose calib= is garbage: the service reports "failed" once, naming the file, and does
    not reopen it (it retried such a file for ever while the reader raised SystemError)."""
    import time

    from fastapi.testclient import TestClient

    from service.app import create_app

    video = tmp_path / "pair.avi"
    writer = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (128, 48))
    for _ in range(3):
        writer.write(np.zeros((48, 128, 3), np.uint8))
    writer.release()
    calib = tmp_path / "stereo.yaml"
    calib.write_bytes(CASES["deep-flow"][0])
    app = create_app(f"video:{video}?calib={calib}", db_path=tmp_path / "h.db", reconnect_initial_s=0.02)
    with TestClient(app, base_url="http://127.0.0.1") as c:
        deadline = time.monotonic() + 20
        while c.get("/api/source").json()["state"] not in ("failed", "streaming") and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.2)  # a retry would show in the count by now (backoff 0.02 s)
        s = c.get("/api/source").json()
    assert s["state"] == "failed" and s["retries"] == 0, s
    assert "CalibrationError" in s["message"] and str(calib) in s["message"], s
