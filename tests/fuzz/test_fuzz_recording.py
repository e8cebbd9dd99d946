"""Fuzzing recordings: manifest.json, frames.jsonl lines and image files mutated field by
field and byte by byte, read through the public reader API (open_recording, Recording.frame,
Recording.raw, summarize).

Every recording either opens or raises RecordingError naming the recording's file; every frame
either reads as a valid Frame or raises RecordingError naming it; reading never changes a byte of
the recording, never raises another exception and never warns.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from device.base import SourceInfo
from device.errors import RecordingError
from device.formats.recording import FRAMES, MANIFEST, Recording, RecordingWriter, open_recording, summarize
from fuzzing import EDGE_FLOATS, ODD_TEXT, byte_edits, typed_or_answer
from measure import Frame, PinholeCamera

W, H = 24, 16
# Each example copies and reads a whole recording: a quarter of the profile's examples per property.
BUDGET = settings(max_examples=max(5, settings.default.max_examples // 4))
CAMERA = PinholeCamera(fx=30.0, fy=30.5, cx=11.5, cy=7.5, width=W, height=H)


def _frame(k: int) -> Frame:
    rng = np.random.default_rng(k)
    d = rng.uniform(0.5, 20.0, (H, W)).astype(np.float32)
    d[rng.random((H, W)) < 0.2] = np.nan
    return Frame(rng.integers(0, 256, (H, W, 3), dtype=np.uint8), d, CAMERA, baseline_m=0.075, doffs=1.0,
                 confidence=rng.random((H, W)).astype(np.float32), timestamp=100.0 + k / 10,
                 meta={"k": k, "gt_disparity": rng.random((H, W)).astype(np.float32)})


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A small valid recording: 3 frames with confidence, a meta array and a raw pair."""
    out = tmp_path_factory.mktemp("rec") / "template"
    with RecordingWriter(out, SourceInfo(kind="sim", name="fuzz", width=W, height=H, fps=10.0), keep_raw=True) as w:
        for k in range(3):
            f = _frame(k)
            w.write(f, raw=(f.image[:, :, 0].copy(), f.image[:, :, 1].copy()))
    return out


def _copy(template: Path, tmp_path_factory) -> Path:
    dst = tmp_path_factory.mktemp("case") / "rec"
    shutil.copytree(template, dst)
    return dst


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


JSON_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**66), 2**66), EDGE_FLOATS.filter(math.isfinite), ODD_TEXT,
    st.sampled_from([0, 1, -1, 2, 10**9, 1e-9, 1e12, "", "color/000000.png", "../manifest.json", "/etc/hostname"]),
)
JSON_VALUES = st.recursive(JSON_SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(ODD_TEXT, inner, max_size=3)), max_leaves=8)


@st.composite
def mutated_value(draw: st.DrawFn, value: object) -> object:
    """``value`` changed a little (numbers scaled or replaced, keys dropped) or replaced by anything."""
    if isinstance(value, dict) and value and draw(st.integers(0, 2)):
        value = dict(value)
        key = draw(st.sampled_from(sorted(value)))
        if draw(st.integers(0, 3)) == 0:
            del value[key]
        else:
            value[key] = draw(mutated_value(value[key]))
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and draw(st.integers(0, 2)):
        return draw(st.one_of(st.sampled_from([0, -1, value * 1000, -value, value + 0.5, 1e308]), st.integers(-5, 10**6)))
    return draw(JSON_VALUES)


@st.composite
def mutated_json(draw: st.DrawFn, doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    for _ in range(draw(st.integers(1, 3))):
        if draw(st.integers(0, 9)) == 0:
            doc[draw(ODD_TEXT)] = draw(JSON_VALUES)
        else:
            doc = draw(mutated_value(doc)) if isinstance(doc, dict) else doc
    return doc


def _read_everything(rec_dir: Path) -> None:
    """Open and read every frame and raw pair, and summarize; check the errors and the answers."""
    before = _digest(rec_dir)
    rec = typed_or_answer(lambda: open_recording(rec_dir), RecordingError)
    if rec is None:
        try:
            open_recording(rec_dir)
        except RecordingError as exc:
            assert str(rec_dir) in str(exc), f"the error does not name the file: {exc}"
        event("open rejected")
    else:
        assert isinstance(rec, Recording)
        for problem in rec.problems:
            assert FRAMES in problem and "line" in problem, problem
        read = 0
        for i in range(len(rec)):
            frame = typed_or_answer(lambda: rec.frame(i), RecordingError)
            if frame is None:
                try:
                    rec.frame(i)
                except RecordingError as exc:
                    assert str(rec_dir) in str(exc), f"the error does not name the file: {exc}"
                continue
            read += 1
            assert isinstance(frame, Frame) and math.isfinite(frame.timestamp)
            typed_or_answer(lambda: rec.raw(i), RecordingError)
        event(f"opened, {read} of {len(rec)} frames read")
        summary = typed_or_answer(lambda: summarize(rec), RecordingError)
        if summary is not None:
            json.dumps(summary, allow_nan=False)  # what `depthruler replay --json` prints
    assert _digest(rec_dir) == before, "reading changed the recording"


@given(data=st.data())
@BUDGET
def test_manifest_mutated_field_by_field(template, tmp_path_factory, data):
    rec = _copy(template, tmp_path_factory)
    doc = json.loads((rec / MANIFEST).read_text())
    (rec / MANIFEST).write_text(json.dumps(data.draw(mutated_json(doc)), ensure_ascii=data.draw(st.booleans())), encoding="utf-8")
    _read_everything(rec)


@given(data=st.data())
@BUDGET
def test_manifest_mutated_byte_by_byte(template, tmp_path_factory, data):
    rec = _copy(template, tmp_path_factory)
    (rec / MANIFEST).write_bytes(data.draw(byte_edits((rec / MANIFEST).read_bytes())))
    _read_everything(rec)


@given(data=st.data())
@BUDGET
def test_frames_jsonl_lines_mutated_field_by_field(template, tmp_path_factory, data):
    rec = _copy(template, tmp_path_factory)
    lines = (rec / FRAMES).read_text().splitlines()
    n = data.draw(st.integers(0, len(lines) - 1))
    lines[n] = json.dumps(data.draw(mutated_json(json.loads(lines[n]))))
    (rec / FRAMES).write_text("\n".join(lines) + "\n", encoding="utf-8")
    _read_everything(rec)


@given(data=st.data())
@BUDGET
def test_frames_jsonl_mutated_byte_by_byte(template, tmp_path_factory, data):
    rec = _copy(template, tmp_path_factory)
    (rec / FRAMES).write_bytes(data.draw(byte_edits((rec / FRAMES).read_bytes())))
    _read_everything(rec)


IMAGES = ["color/000001.png", "disparity/000001.png", "confidence/000001.png", "raw/left/000001.png"]


@given(data=st.data())
@BUDGET
def test_image_files_mutated_byte_by_byte(template, tmp_path_factory, data):
    rec = _copy(template, tmp_path_factory)
    target = rec / data.draw(st.sampled_from(IMAGES + [str(p.relative_to(template)) for p in template.glob("extra/*/*")]))
    op = data.draw(st.integers(0, 3))
    if op == 0:  # another valid image in its place: other size, channels or depth
        img = np.zeros((data.draw(st.integers(1, 40)), data.draw(st.integers(1, 40)), data.draw(st.sampled_from([1, 3, 4]))),
                       data.draw(st.sampled_from([np.uint8, np.uint16])))
        cv2.imwrite(str(target.with_suffix(".png")), img)
        if target.suffix != ".png":
            target.write_bytes(target.with_suffix(".png").read_bytes())
    elif op == 1:
        target.unlink()
    else:
        target.write_bytes(data.draw(byte_edits(target.read_bytes())))
    _read_everything(rec)


def test_frame_files_outside_the_recording_are_refused(template, tmp_path_factory):
    """A frames.jsonl line naming ../x.png or /abs/x.png never reads that file: the line is refused
    (skipped, with its file, line and field in ``problems``) and the other frames stay readable."""
    rec = _copy(template, tmp_path_factory)
    outside = rec.parent / "outside.png"
    shutil.copy(rec / "color" / "000000.png", outside)
    lines = (rec / FRAMES).read_text().splitlines()
    for name in ("../outside.png", str(outside)):
        entry = json.loads(lines[0])
        entry["files"]["color"] = name
        (rec / FRAMES).write_text("\n".join([json.dumps(entry), *lines[1:]]) + "\n")
        opened = open_recording(rec)
        assert len(opened) == len(lines) - 1
        assert any("line 1" in p and "files.color" in p for p in opened.problems), opened.problems
        assert all(opened.frame(i).image.shape for i in range(len(opened)))
