"""What the CLI says to a newcomer's slips: bare paths as sources, bad numbers, boards that fit no paper,
measurements from another source, where saved frames go. Each refusal is one line naming what to change."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cli.main import app
from cli.specs import source_spec
from device import SourceInfo, SourceNotFound
from device.formats.recording import RecordingWriter
from factories import SMALL_H, SMALL_W, WALL_DISP, wall_frame

ROOT = Path(__file__).resolve().parents[2]
POINTS = ["--p1", "40,30", "--p2", "280,200"]


@pytest.fixture
def recording(tmp_path):
    out = tmp_path / "rec"
    with RecordingWriter(out, SourceInfo(kind="plane", name="Fake plane", width=SMALL_W, height=SMALL_H, fps=30.0)) as rec:
        for i in range(2):
            rec.write(replace(wall_frame(i), disparity=np.full((SMALL_H, SMALL_W), WALL_DISP, np.float32)))
    return out


def one_line(result) -> str:
    """The refusal on stderr, asserted to be a single line."""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    return lines[0]


def test_bare_paths_are_read_as_the_kind_they_hold(tmp_path):
    """A recording, a bag, a video (one file or LEFT,RIGHT), a Middlebury scene and a depth-PNG folder are
    each given their kind; options after ``?`` stay theirs; specs with a kind are left as typed."""
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "manifest.json").write_text("{}")
    scene = tmp_path / "Teddy"
    scene.mkdir()
    (scene / "im0.png").write_bytes(b"")
    (scene / "calib.txt").write_text("")
    depth = tmp_path / "d435"
    (depth / "depth").mkdir(parents=True)
    for name in ("pair.mkv", "left.mp4", "right.mp4", "run.bag"):
        (tmp_path / name).write_bytes(b"")
    t = str(tmp_path)
    assert source_spec(f"{rec}?loop=1") == f"replay:{rec}?loop=1"
    assert source_spec(f"{t}/run.bag") == f"bag:{t}/run.bag"
    assert source_spec(f"{t}/pair.mkv?calib=s.yaml") == f"video:{t}/pair.mkv?calib=s.yaml"
    assert source_spec(f"{t}/left.mp4,{t}/right.mp4") == f"video:{t}/left.mp4,{t}/right.mp4"
    assert source_spec(str(scene)) == f"middlebury:{scene}"
    assert source_spec(str(depth)) == f"depthpng:{depth}"
    for typed in ("sim:poster?distance=3", "oak", "kinect:0", f"replay:{t}/nope"):
        assert source_spec(typed) == typed
    with pytest.raises(SourceNotFound, match="is a folder but holds no recording"):
        source_spec(t + "/d435/depth")
    with pytest.raises(SourceNotFound, match="is a file but holds neither a bag"):
        source_spec(f"{scene}/calib.txt")


def test_measure_says_what_a_bare_path_is_not(tmp_path):
    """`measure rec/desk` used to answer "unknown source kind 'rec/desk'" for a missing folder and for a
    folder that holds no recording alike; now each says what it is and what to pass."""
    (tmp_path / "empty").mkdir()
    missing = CliRunner().invoke(app, ["measure", str(tmp_path / "desk"), *POINTS])
    assert missing.exit_code == 1
    line = one_line(missing)
    assert f"'{tmp_path / 'desk'}' is no source kind and no existing file or folder" in line and "replay:rec/desk" in line
    empty = CliRunner().invoke(app, ["measure", str(tmp_path / "empty"), *POINTS])
    assert empty.exit_code == 1
    assert f"{tmp_path / 'empty'} is a folder but holds no recording (manifest.json)" in one_line(empty)


def test_measure_reads_a_bare_video_file_as_video(tmp_path):
    """A video file typed bare is opened as `video:` (which then asks for the calibration a pair needs)."""
    import cv2

    path = tmp_path / "pair.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 10, (64, 32))
    writer.write(np.zeros((32, 64, 3), np.uint8))
    writer.release()
    res = CliRunner().invoke(app, ["measure", str(path), "--p1", "5,5", "--p2", "20,20"])
    assert res.exit_code == 1
    assert "unknown source kind" not in res.stderr and "needs its calibration: add calib=FILE" in one_line(res)


@pytest.mark.parametrize("command", [["measure", "REC", *POINTS], ["record", "--source", "REC", "--out", "OUT", "--frames", "1"],
                                     ["check", "--source", "REC", "--no-history"]])
def test_a_negative_timeout_is_refused_on_one_line(recording, tmp_path, command):
    args = [str(recording) if a == "REC" else str(tmp_path / "out") if a == "OUT" else a for a in command]
    res = CliRunner().invoke(app, [*args, "--timeout", "-1"])
    assert res.exit_code == 2
    line = one_line(res)
    assert "Invalid value for '--timeout'" in line and "0.01" in line and line.endswith(f"{command[0]} --help)")
    assert not (tmp_path / "out").exists()


def test_check_names_the_square_size_on_one_line(recording):
    res = CliRunner().invoke(app, ["check", "--source", str(recording), "--square-mm", "-60", "--no-history"])
    assert res.exit_code == 2
    line = one_line(res)
    assert "--square-mm: -60 is not a length" in line and "--marker-mm" not in line


@pytest.mark.parametrize("flag, value, says", [
    ("--port", "70000", "70000 is out of range; give a whole number from 1 to 65535"),
    ("--port", "http", "'http' is not a whole number; give a whole number from 1 to 65535"),
    ("--ring-size", "1", "1 is out of range; give a whole number from 2 to 4096"),
    ("--header-timeout", "-1", "-1 is out of range; give a number above 0, at most 3600"),
])  # fmt: skip
def test_serve_refuses_a_bad_number_on_one_line_with_its_range(tmp_path, flag, value, says):
    res = CliRunner().invoke(app, ["serve", "--source", "sim", flag, value, "--db", str(tmp_path / "s.db")])
    assert res.exit_code == 2
    line = one_line(res)
    assert f"Invalid value for '{flag}': {says}" in line and "pydantic" not in line
    assert not (tmp_path / "s.db").exists()


def test_a_server_setting_out_of_range_reads_as_one_line():
    from pydantic import ValidationError

    from cli.serve import FLAGS
    from service.config import ServerConfig, describe_validation

    with pytest.raises(ValidationError) as err:
        ServerConfig.model_validate({"port": 70000, "keep_alive_s": 0})
    assert describe_validation(err.value, FLAGS) == (
        "--port 70000 is out of range; give a value from 1 to 65535; "
        "--keep-alive 0 is out of range; give a value above 0, at most 3600")


def test_board_png_warns_when_the_sheet_fits_no_paper(tmp_path):
    """The default 11x8 x 30 mm board prints 350 x 260 mm; --board/--paper a4|letter print the largest that fits."""
    from check.boards import papers_that_fit

    assert papers_that_fit(350, 260) == [] and papers_that_fit(300, 220) == []
    assert papers_that_fit(263, 194) == ["a4", "letter"] and papers_that_fit(194, 263) == ["a4", "letter"]
    assert papers_that_fit(280, 190) == ["a4"]  # wider than Letter's printable 266.7 mm
    runner = CliRunner()
    big = runner.invoke(app, ["calibrate", "--board-png", str(tmp_path / "big.png"), "--dpi", "72"])
    assert big.exit_code == 0, big.output
    assert "warning: a 350 x 260 mm sheet fits neither A4 nor US Letter at 100 %; pass --board a4 or --board letter" in one_line(big)
    for paper in ("a4", "letter"):
        fits = runner.invoke(app, ["calibrate", "--board-png", str(tmp_path / f"{paper}.png"), "--paper", paper, "--dpi", "72"])
        assert fits.exit_code == 0 and not fits.stderr and f"fits {paper}" in fits.stdout
    own = runner.invoke(app, ["calibrate", "--board-png", str(tmp_path / "own.png"), "--dpi", "72", "--squares", "7x5",
                              "--square-mm", "35", "--marker-mm", "26"])  # fmt: skip
    assert own.exit_code == 0 and not own.stderr  # the board docs/check.md suggests


def test_export_warns_about_measurements_made_on_another_source(recording, tmp_path):
    """A measurement from a live camera, the simulator or a bag names a frame of *its* stream: it used to
    be drawn on that frame of this recording without a word."""
    base = {"distance_m": 1.0, "p1": [40, 30], "p2": [280, 200]}
    meas = [{**base, "frame_index": 1, "source": str(recording)},  # the bare folder is this recording: fine
            {**base, "frame_index": 1, "source": "oak"},
            {**base, "frame_index": 0, "source": "sim:poster?distance=3"},
            {**base, "frame_index": 1, "source": f"bag:{tmp_path / 'run.bag'}"}]  # fmt: skip
    (tmp_path / "m.json").write_text(json.dumps(meas))
    res = CliRunner().invoke(app, ["export", str(recording), "--mcap", str(tmp_path / "o.mcap"), "--measurements", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    warned = [" ".join(w.split()) for w in res.stderr.split("warning: ")[1:]]
    assert [w.split(" were made on ")[1].split(",")[0] for w in warned] == ["oak", "sim:poster?distance=3", f"bag:{tmp_path / 'run.bag'}"]
    assert warned[0].startswith("1 measurement(s) (1) were made on oak, not on") and f"made on replay:{recording}" in warned[0]
    assert not any("(0)" in w for w in warned)


def test_saved_frames_go_where_the_help_and_the_manual_say(tmp_path):
    """`<db stem>-frames/` beside the database, as the help and docs/operating.md now spell it (they said `<db>-frames/`)."""
    from history.schema import frames_dir

    assert frames_dir(tmp_path / "station.db") == tmp_path / "station-frames"
    help_text = " ".join(CliRunner().invoke(app, ["serve", "--help"], env={"COLUMNS": "400"}).output.split())
    assert "Saved frames go to <db stem>-frames/ beside it." in help_text
    for page in ("docs/operating.md", "docs/decisions/full-disk.md"):
        text = (ROOT / page).read_text()
        assert "<db stem>-frames/" in text and "<db>-frames" not in text, page


@given(st.one_of(st.text(max_size=40), st.text(max_size=8).map(lambda t: "x" * 300 + t), st.sampled_from(["~nouser/r", "a\x00b", ","])))
@settings(max_examples=60, deadline=None, database=None)
def test_any_typed_source_is_a_spec_or_a_typed_refusal(text):
    """Names the file system cannot hold (too long, a NUL byte, an unknown ~user) are refused like any missing path."""
    from device.errors import SourceError

    try:
        assert isinstance(source_spec(text), str)
    except SourceError as exc:
        assert "no source kind" in str(exc) or " but holds " in str(exc)


def test_serve_and_record_take_a_bare_recording_folder(recording, tmp_path, monkeypatch):
    import uvicorn
    from server_process import free_port

    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: None)
    served = CliRunner().invoke(app, ["serve", "--source", str(recording), "--port", str(free_port()), "--db", str(tmp_path / "s.db")])
    assert served.exit_code == 0, served.output
    assert f"source replay:{recording};" in served.stderr
    copied = CliRunner().invoke(app, ["record", "--source", str(recording), "--out", str(tmp_path / "copy"), "--frames", "2"])
    assert copied.exit_code == 0, copied.output
    assert "2 frames" in copied.stdout and (tmp_path / "copy" / "manifest.json").is_file()
