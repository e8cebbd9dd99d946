"""The recording reader on hostile input: type-wrong values in valid JSON and paths out of the recording
give a RecordingError naming the file, the line and the field, never a TypeError or a read elsewhere."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from factories import assert_same_frame, record

from device.errors import RecordingError
from device.formats.recording import FRAMES, MANIFEST, ReplaySource, open_recording


def _edit_line(rec: Path, n: int, change) -> None:
    lines = (rec / FRAMES).read_text().splitlines()
    obj = json.loads(lines[n - 1])
    change(obj)
    lines[n - 1] = json.dumps(obj)
    (rec / FRAMES).write_text("\n".join(lines) + "\n")


def _set(path: str, value):
    def change(obj):
        *head, last = path.split(".")
        for k in head:
            obj = obj.setdefault(k, {})
        obj[last] = value

    return change


@pytest.mark.parametrize(
    "field, value",
    [
        ("files.color", 5),
        ("files.disparity", None),
        ("files.confidence", ["a"]),
        ("files", 5),
        ("files", []),
        ("calib", {"camera": 1}),
        ("calib", {"camera": {"fx": "a", "fy": 1, "cx": 1, "cy": 1, "width": 96, "height": 64}, "baseline_m": 0.1, "doffs": 0}),
        ("calib", {"camera": {"fx": 80, "fy": 80, "cx": 1, "cy": 1, "width": 96, "height": 64}, "baseline_m": 0.1, "doffs": "abc"}),
        ("calib", 7),
        ("timestamp", "noon"),
        ("timestamp", None),
        ("index", "two"),
        ("index", 1.5),
        ("meta", 5),
        ("disparity_dropped", "many"),
        ("meta_dropped", 3),
    ],
)
def test_type_wrong_line_is_a_recording_error_naming_file_line_field(tmp_path: Path, field: str, value) -> None:
    frames = record(tmp_path / "rec", 3)
    _edit_line(tmp_path / "rec", 2, _set(field, value))
    with pytest.raises(RecordingError) as exc:
        open_recording(tmp_path / "rec", strict=True)
    msg = str(exc.value)
    assert str(tmp_path / "rec" / FRAMES) in msg and "line 2" in msg and field.split(".")[0] in msg, msg
    rec = open_recording(tmp_path / "rec")  # not strict: that frame is skipped, the others replay
    assert [e.index for e in rec.entries] == [0, 2]
    assert "line 2" in rec.problems[0] and field.split(".")[0] in rec.problems[0]
    assert_same_frame(rec.frame(1), frames[2])
    with ReplaySource(tmp_path / "rec") as src:
        assert [src.read().meta["k"] for _ in range(2)] == [0, 2]


@pytest.mark.parametrize(
    "field, value",
    [("doffs", "abc"), ("baseline_m", "far"), ("camera", {"camera": 1}), ("camera", 5), ("camera.fx", "a"), ("camera.width", -3),
     ("camera.width", 9.5), ("source", 5), ("source.fps", "fast"), ("source.width", "wide"), ("source.extra", 3)],
)  # fmt: skip
def test_type_wrong_manifest_is_a_recording_error_naming_the_field(tmp_path: Path, field: str, value) -> None:
    record(tmp_path / "rec", 2)
    m = json.loads((tmp_path / "rec" / MANIFEST).read_text())
    _set(field, value)(m)
    (tmp_path / "rec" / MANIFEST).write_text(json.dumps(m))
    with pytest.raises(RecordingError) as exc:
        open_recording(tmp_path / "rec")
    assert str(tmp_path / "rec" / MANIFEST) in str(exc.value) and field in str(exc.value), str(exc.value)


@pytest.mark.parametrize("rel", ["/etc/hostname", "../outside.png", "color/../../outside.png", "color\\..\\..\\x.png", ""])
def test_paths_out_of_the_recording_are_refused(tmp_path: Path, rel: str) -> None:
    record(tmp_path / "rec", 3)
    (tmp_path / "outside.png").write_bytes((tmp_path / "rec" / "color" / "000000.png").read_bytes())
    _edit_line(tmp_path / "rec", 2, _set("files.color", rel))
    with pytest.raises(RecordingError) as exc:
        open_recording(tmp_path / "rec", strict=True)
    assert "line 2" in str(exc.value) and "files.color" in str(exc.value) and "inside the recording" in str(exc.value)
    assert len(open_recording(tmp_path / "rec")) == 2


def test_symlink_out_of_the_recording_is_refused(tmp_path: Path) -> None:
    record(tmp_path / "rec", 2)
    (tmp_path / "secret.png").write_bytes((tmp_path / "rec" / "color" / "000000.png").read_bytes())
    link = tmp_path / "rec" / "color" / "000001.png"
    link.unlink()
    link.symlink_to(tmp_path / "secret.png")
    rec = open_recording(tmp_path / "rec")
    with pytest.raises(RecordingError, match="outside the recording"):
        rec.frame(1)
