"""`depthruler record` and `depthruler replay` through typer's CliRunner."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import typer
from factories import assert_same_frame, record
from typer.testing import CliRunner

from device.formats.recording import open_recording
from cli.recording import record as record_cmd
from cli.recording import replay as replay_cmd

app = typer.Typer()
app.command("record")(record_cmd)
app.command("replay")(replay_cmd)
runner = CliRunner()


@pytest.fixture()
def source_rec(tmp_path: Path) -> tuple[Path, list]:
    frames = record(tmp_path / "src", 3)
    return tmp_path / "src", frames


def test_record_frames(tmp_path: Path, source_rec) -> None:
    src, frames = source_rec
    out = tmp_path / "out"
    result = runner.invoke(app, ["record", "--source", f"replay:{src}", "--frames", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "3 frames" in result.output and "per frame" in result.output and str(out) in result.output
    rec = open_recording(out)
    assert len(rec) == 3 and rec.manifest["complete"] is True and rec.source.kind == "replay"
    for k in range(3):
        assert_same_frame(rec.frame(k), frames[k])


def test_record_stops_at_end_of_source_and_by_seconds(tmp_path: Path, source_rec) -> None:
    src, _ = source_rec
    result = runner.invoke(app, ["record", "--source", f"replay:{src}", "--frames", "10", "--out", str(tmp_path / "a")])
    assert result.exit_code == 0, result.output
    assert "reached its end" in result.output and len(open_recording(tmp_path / "a")) == 3
    result = runner.invoke(app, ["record", "--source", f"replay:{src}?loop=1", "--seconds", "0.3", "--out", str(tmp_path / "b")])
    assert result.exit_code == 0, result.output
    assert len(open_recording(tmp_path / "b")) >= 1


def test_record_bad_usage(tmp_path: Path, source_rec) -> None:
    src, _ = source_rec
    both = runner.invoke(app, ["record", "--source", f"replay:{src}", "--frames", "1", "--seconds", "1", "--out", str(tmp_path / "x")])
    assert both.exit_code == 2 and "exactly one" in both.output
    neither = runner.invoke(app, ["record", "--source", f"replay:{src}", "--out", str(tmp_path / "x")])
    assert neither.exit_code == 2
    missing = runner.invoke(app, ["record", "--source", f"replay:{tmp_path / 'nope'}", "--frames", "1", "--out", str(tmp_path / "x")])
    assert missing.exit_code == 1 and "does not exist" in missing.output
    # an existing recording is only replaced with --overwrite
    again = runner.invoke(app, ["record", "--source", f"replay:{src}", "--frames", "1", "--out", str(src)])
    assert again.exit_code == 1 and "--overwrite" in again.output
    assert len(open_recording(src)) == 3
    copy = tmp_path / "copy"
    assert runner.invoke(app, ["record", "--source", f"replay:{src}", "--frames", "2", "--out", str(copy)]).exit_code == 0
    ok = runner.invoke(app, ["record", "--source", f"replay:{src}?start=2", "--frames", "1", "--out", str(copy), "--overwrite"])
    assert ok.exit_code == 0, ok.output
    assert len(open_recording(copy)) == 1 and open_recording(copy).frame(0).meta["k"] == 2


def test_replay_inspects(tmp_path: Path, source_rec) -> None:
    src, frames = source_rec
    text = runner.invoke(app, ["replay", str(src)])
    assert text.exit_code == 0, text.output
    assert "frames     3" in text.output and "96x64" in text.output and "baseline 0.0625" in text.output
    as_json = runner.invoke(app, ["replay", str(src), "--json"])
    info = json.loads(as_json.output)
    shares = [float(np.isfinite(f.disparity).mean()) for f in frames]
    assert info["frames"] == 3 and info["problems"] == [] and info["complete"] is True
    assert info["valid_disparity"]["per_frame"] == [round(s, 4) for s in shares]
    assert info["valid_disparity"]["median"] == pytest.approx(float(np.median(shares)))
    assert info["fps"] == pytest.approx(30.0)


def test_replay_reports_damage(tmp_path: Path, source_rec) -> None:
    src, _ = source_rec
    victim = src / "color" / "000001.png"
    victim.unlink()
    result = runner.invoke(app, ["replay", str(src)])
    assert result.exit_code == 1 and str(victim) in result.output and "frames     3" in result.output
    (src / "frames.jsonl").write_bytes((src / "frames.jsonl").read_bytes()[:-20])
    info = json.loads(runner.invoke(app, ["replay", str(src), "--json"]).output)
    assert info["frames"] == 2 and any("incomplete" in p for p in info["problems"])
    newer = json.loads((src / "manifest.json").read_text())
    newer["format_version"] = 9
    (src / "manifest.json").write_text(json.dumps(newer))
    bad = runner.invoke(app, ["replay", str(src)])
    assert bad.exit_code == 1 and "upgrade depthruler" in bad.output
