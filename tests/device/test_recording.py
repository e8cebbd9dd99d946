"""Recording format: round trips (synthetic, simulator, Middlebury), replay source, and bad input."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import numpy as np
import pytest

from device import SourceDisconnected, SourceNotFound, SourceTimeout, open_source
from device.base import SourceInfo
from device.errors import RecordingError, SourceError
from device.formats.recording import (
    FRAMES,
    MANIFEST,
    EndOfRecording,
    RecordingWriter,
    ReplayConfig,
    ReplaySource,
    decode_disparity,
    encode_disparity,
    open_recording,
    summarize,
)
from factories import SYNTH_CAM, SYNTH_H, SYNTH_INFO, SYNTH_W, assert_same_frame, record, synthetic_frame
from measure import Frame

W, H, CAMERA, INFO = SYNTH_W, SYNTH_H, SYNTH_CAM, SYNTH_INFO


def test_synthetic_round_trip(tmp_path: Path) -> None:
    frames = record(tmp_path / "rec", 3)
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == 3 and rec.problems == ()
    for k, want in enumerate(frames):
        got = rec.frame(k)
        assert_same_frame(got, want)
        assert got.meta["k"] == k and got.meta["gain"] == 1.25 and "handle" not in got.meta
        truth = got.meta["truth"]
        assert truth["_type"] == "Truth" and truth["length_m"] == 0.5 and truth["p2_px"] == [60.0, 20.0]
        assert "depth_m" not in truth
        assert rec.entries[k].meta_dropped == ("handle",)
    m = rec.manifest
    assert m["format_version"] == 1 and m["frame_count"] == 3 and m["complete"] is True
    assert rec.camera == CAMERA and rec.baseline_m == 0.0625 and rec.doffs == 1.5
    assert rec.source.serial == "S1" and rec.source.extra == {"n": 2}
    line = json.loads((tmp_path / "rec" / FRAMES).read_text().splitlines()[0])
    assert line["files"]["disparity"] == "disparity/000000.png" and line["index"] == 0


def test_disparity_codes_and_limits(tmp_path: Path) -> None:
    d = np.array([[np.nan, 0.0, -3.0, 0.004, 0.01, 1023.98, 12.34567, np.inf]], np.float32)
    code, dropped = encode_disparity(d)
    assert code.tolist() == [[0, 0, 0, 0, 1, 65535, 790, 0]]
    assert dropped == 4  # 0, -3, 0.004 (< 1/128 px) and inf cannot be stored
    back = decode_disparity(code)
    assert back[0, 6] == np.float32(790 / 64) and abs(back[0, 6] - 12.34567) <= 1 / 128
    with pytest.raises(RecordingError, match="1024|1023"):
        encode_disparity(np.array([[1024.0]], np.float32))

    bad = synthetic_frame(1)
    bad.disparity[5, 5] = 2000.0
    with RecordingWriter(tmp_path / "rec", INFO) as w:
        w.write(synthetic_frame(0))
        with pytest.raises(RecordingError, match="beyond what the 16-bit"):
            w.write(bad)
        assert w.write(synthetic_frame(2)) == 1  # the writer stays usable; nothing of the bad frame was kept
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == 2 and sorted(p.name for p in (tmp_path / "rec" / "color").iterdir()) == ["000000.png", "000001.png"]
    assert_same_frame(rec.frame(1), synthetic_frame(2))


def test_negative_disparity_is_counted(tmp_path: Path) -> None:
    f = synthetic_frame(0)
    f.disparity[0, :10] = -2.0
    with RecordingWriter(tmp_path / "rec", INFO) as w:
        w.write(f)
    rec = open_recording(tmp_path / "rec")
    assert rec.entries[0].disparity_dropped == 10
    assert np.isnan(rec.frame(0).disparity[0, :10]).all()


def test_calibration_change_mid_recording(tmp_path: Path) -> None:
    a = synthetic_frame(0)
    b = Frame(**{**synthetic_frame(1).__dict__, "baseline_m": 0.08, "doffs": 0.0})
    with RecordingWriter(tmp_path / "rec", INFO) as w:
        w.write(a)
        w.write(b)
    rec = open_recording(tmp_path / "rec")
    assert rec.baseline_m == 0.0625
    assert_same_frame(rec.frame(0), a)
    assert_same_frame(rec.frame(1), b)


def test_keep_raw_and_meta_arrays(tmp_path: Path) -> None:
    f = synthetic_frame(0)
    gt = np.random.default_rng(5).uniform(1, 50, (H, W)).astype(np.float32)
    gt[0, 0] = np.nan
    f = Frame(**{**f.__dict__, "meta": {"gt_disparity": gt}})
    left = np.random.default_rng(1).integers(0, 256, (H, W, 3), dtype=np.uint8)
    right = np.random.default_rng(2).integers(0, 256, (H, W), dtype=np.uint8)
    with RecordingWriter(tmp_path / "rec", INFO, keep_raw=True) as w:
        w.write(f, raw=(left, right))
        w.write(synthetic_frame(1))
    rec = open_recording(tmp_path / "rec")
    got = rec.frame(0)
    assert np.array_equal(got.meta["gt_disparity"], gt, equal_nan=True) and got.meta["gt_disparity"].dtype == np.float32
    l2, r2 = rec.raw(0)
    assert np.array_equal(l2, left) and np.array_equal(r2, right)
    assert rec.raw(1) is None
    without = tmp_path / "noraw"
    with RecordingWriter(without, INFO) as w:
        w.write(f, raw=(left, right))
    assert open_recording(without).raw(0) is None and not (without / "raw").exists()
    via_meta = tmp_path / "viameta"  # sources hand the pair over in meta, as `depthruler record --keep-raw` expects
    with RecordingWriter(via_meta, INFO, keep_raw=True) as w:
        w.write(Frame(**{**f.__dict__, "meta": {"raw_left": left, "raw_right": right, "k": 3}}))
    rec = open_recording(via_meta)
    assert np.array_equal(rec.raw(0)[1], right) and rec.frame(0).meta == {"k": 3}


def test_non_finite_timestamp_is_refused(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec", INFO) as w:
        with pytest.raises(RecordingError, match="timestamp"):
            w.write(Frame(**{**synthetic_frame(0).__dict__, "timestamp": float("nan")}))
        assert w.write(synthetic_frame(1)) == 0
    assert len(open_recording(tmp_path / "rec")) == 1


@pytest.mark.slow
def test_sim_round_trip(tmp_path: Path) -> None:
    with open_source("sim?fps=0") as src:
        frames = [src.read() for _ in range(2)]
        info = src.info
    with RecordingWriter(tmp_path / "rec", info) as w:
        for f in frames:
            w.write(f)
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == 2
    for got, want in zip(rec.frames(), frames):
        assert_same_frame(got, want)
        truth, summary = want.meta["truth"], got.meta["truth"]
        assert summary["_type"] == "Truth" and "depth_m" not in summary
        assert summary["length_m"] == truth.length_m and summary["target"] == truth.target
        assert summary["is_gap"] == truth.is_gap and np.allclose(summary["p1_m"], truth.p1_m, rtol=0, atol=0)
        assert np.allclose(summary["p2_px"], truth.p2_px, rtol=0, atol=0)
    assert rec.camera == frames[0].camera and rec.baseline_m == frames[0].baseline_m


def test_middlebury_round_trip(tmp_path: Path, middlebury_dir: Path) -> None:
    from device.sources import middlebury as mb

    scene = mb.load_scene(middlebury_dir / "Adirondack")
    frame = mb.scene_frame(scene, scene.gt_disparity)
    with RecordingWriter(tmp_path / "rec", SourceInfo(kind="middlebury", name=scene.name), keep_raw=True) as w:
        w.write(frame, raw=(scene.left, scene.right))
    with ReplaySource(tmp_path / "rec") as src:
        got = src.read()
        with pytest.raises(EndOfRecording):
            src.read()
    assert_same_frame(got, frame)
    err = np.nanmax(np.abs(got.disparity - frame.disparity))
    assert err <= 1 / 128
    assert np.array_equal(got.meta["gt_disparity"], scene.gt_disparity, equal_nan=True)
    rec = open_recording(tmp_path / "rec")
    assert rec.camera == scene.camera and rec.baseline_m == scene.baseline_m and rec.doffs == scene.doffs
    left, right = rec.raw(0)
    assert np.array_equal(left, scene.left) and np.array_equal(right, scene.right)


def test_middlebury_source_recorded_and_replayed(tmp_path: Path, middlebury_dir: Path) -> None:
    with open_source(f"middlebury:{middlebury_dir / 'Teddy'}?disparity=gt") as src:
        want = src.read()
        with RecordingWriter(tmp_path / "rec", src.info) as w:
            w.write(want)
    with open_source(f"replay:{tmp_path / 'rec'}") as rp:
        assert rp.info.kind == "replay" and rp.info.name == "Teddy"
        got = rp.read()
    assert_same_frame(got, want)


def test_replay_source_loop_and_end(tmp_path: Path) -> None:
    frames = record(tmp_path / "rec", 3)
    with open_source(f"replay:{tmp_path / 'rec'}") as src:
        assert (src.info.width, src.info.height, src.info.fps) == (W, H, 30.0)
        got = [src.read() for _ in range(3)]
        with pytest.raises(EndOfRecording) as exc:
            src.read()
        assert isinstance(exc.value, SourceDisconnected) and "loop=1" in str(exc.value)
    for g, f in zip(got, frames):
        assert_same_frame(g, f)
    assert got[2].meta["replay"]["index"] == 2
    with open_source(f"replay:{tmp_path / 'rec'}?loop=1&start=2") as src:
        ks = [src.read().meta["k"] for _ in range(4)]
    assert ks == [2, 0, 1, 2]


def test_replay_realtime_paces_by_timestamps(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path / "rec", INFO) as w:
        w.write(Frame(**{**synthetic_frame(0).__dict__, "timestamp": 5.0}))
        w.write(Frame(**{**synthetic_frame(1).__dict__, "timestamp": 65.0}))  # one minute later
    with ReplaySource(ReplayConfig(path=tmp_path / "rec", realtime=True)) as src:
        assert src.read(timeout_s=0.05).timestamp == 5.0
        with pytest.raises(SourceTimeout, match="due in"):
            src.read(timeout_s=0.05)
    with ReplaySource(ReplayConfig(path=tmp_path / "rec", realtime=True, speed=600.0)) as src:
        assert [src.read(timeout_s=1.0).timestamp for _ in range(2)] == [5.0, 65.0]  # 60 s / 600 = 0.1 s


def test_replay_spec_errors(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match="unknown replay option"):
        open_source(f"replay:{tmp_path}?bogus=1")
    with pytest.raises(SourceError, match="yes/no"):
        open_source(f"replay:{tmp_path}?loop=maybe")
    with pytest.raises(SourceNotFound, match="does not exist"):
        open_source(f"replay:{tmp_path / 'nothing'}")
    with RecordingWriter(tmp_path / "empty", INFO):
        pass
    with pytest.raises(RecordingError, match="no complete frame"):
        open_source(f"replay:{tmp_path / 'empty'}")


# ------------------------------------------------------------------------------------------
# bad input: each names the file, and every complete frame stays readable


def test_truncated_last_line(tmp_path: Path) -> None:
    frames = record(tmp_path / "rec", 4)
    fpath = tmp_path / "rec" / FRAMES
    data = fpath.read_bytes()
    last_start = data.rstrip(b"\n").rfind(b"\n") + 1
    fpath.write_bytes(data[: last_start + (len(data) - last_start) // 2])
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == 3
    assert len(rec.problems) == 1 and str(fpath) in rec.problems[0] and "incomplete" in rec.problems[0]
    for k in range(3):
        assert_same_frame(rec.frame(k), frames[k])
    with pytest.raises(RecordingError) as exc:
        open_recording(tmp_path / "rec", strict=True)
    assert str(fpath) in str(exc.value) and "without strict" in str(exc.value)


def test_corrupt_middle_line_is_skipped(tmp_path: Path) -> None:
    frames = record(tmp_path / "rec", 3)
    fpath = tmp_path / "rec" / FRAMES
    lines = fpath.read_text().splitlines(keepends=True)
    lines[1] = '{"index": 1, "timest\n'
    fpath.write_text("".join(lines))
    rec = open_recording(tmp_path / "rec")
    assert [e.index for e in rec.entries] == [0, 2] and "line 2" in rec.problems[0]
    assert_same_frame(rec.frame(1), frames[2])


@pytest.mark.parametrize("damage", ["missing", "garbage", "truncated"])
def test_missing_or_corrupt_png(tmp_path: Path, damage: str) -> None:
    frames = record(tmp_path / "rec", 4)
    victim = tmp_path / "rec" / ("disparity/000001.png" if damage == "missing" else "color/000002.png")
    if damage == "missing":
        victim.unlink()
    elif damage == "garbage":
        victim.write_bytes(b"not a png at all" * 10)
    else:
        victim.write_bytes(victim.read_bytes()[:200])
    bad = 1 if damage == "missing" else 2
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == 4
    with pytest.raises(RecordingError) as exc:
        rec.frame(bad)
    assert str(victim) in str(exc.value) and ("missing" in str(exc.value) or "corrupt" in str(exc.value))
    for k in range(4):
        if k != bad:
            assert_same_frame(rec.frame(k), frames[k])
    s = summarize(rec)
    assert s["unreadable_frames"] == 1 and any(str(victim) in p for p in s["problems"])
    with ReplaySource(tmp_path / "rec") as src:  # a replay skips the frame, says so, and carries on to the end
        got = [src.read().meta["k"] for _ in range(3)]
        with pytest.raises(EndOfRecording):
            src.read()
    assert got == [k for k in range(4) if k != bad]
    assert len(src.warnings) == 1 and str(victim) in src.warnings[0] and f"frame {bad} skipped" in src.warnings[0]


def test_newer_format_version(tmp_path: Path) -> None:
    record(tmp_path / "rec", 2)
    mpath = tmp_path / "rec" / MANIFEST
    original = mpath.read_text()
    manifest = json.loads(original)
    manifest["format_version"] = 2
    mpath.write_text(json.dumps(manifest))
    index_before = (tmp_path / "rec" / FRAMES).read_bytes()
    with pytest.raises(RecordingError) as exc:
        open_recording(tmp_path / "rec")
    assert str(mpath) in str(exc.value) and "upgrade depthruler" in str(exc.value)
    assert (tmp_path / "rec" / FRAMES).read_bytes() == index_before  # reading never modifies
    mpath.write_text(original)
    assert len(open_recording(tmp_path / "rec")) == 2


def test_missing_or_damaged_manifest(tmp_path: Path) -> None:
    record(tmp_path / "rec", 1)
    mpath = tmp_path / "rec" / MANIFEST
    mpath.write_text("{ not json")
    with pytest.raises(RecordingError, match="manifest.json cannot be read"):
        open_recording(tmp_path / "rec")
    mpath.unlink()
    with pytest.raises(RecordingError, match="manifest.json is missing"):
        open_recording(tmp_path / "rec")
    (tmp_path / "plain").mkdir()
    with pytest.raises(SourceNotFound, match="not a depthruler recording"):
        open_recording(tmp_path / "plain")


def _fail_on(monkeypatch: pytest.MonkeyPatch, target: str, when: str, partial: bool = False) -> None:
    import device.formats.recording.writer as r  # where the writer looks these up

    real = getattr(r, target)

    def failing(where, data):
        name = str(where) if target == "_write_file" else data.decode()
        if when in name:
            if partial:
                os.write(where, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(where, data)

    monkeypatch.setattr(r, target, failing)


@pytest.mark.parametrize("where", ["disparity", "frames.jsonl"])
def test_disk_full_mid_recording(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str) -> None:
    frames = [synthetic_frame(k) for k in range(5)]
    out = tmp_path / "rec"
    with RecordingWriter(out, INFO) as w:
        for k in range(3):
            w.write(frames[k])
        if where == "disparity":
            _fail_on(monkeypatch, "_write_file", "disparity/000003.png")
            failing_file = out / "disparity" / "000003.png"
        else:
            _fail_on(monkeypatch, "_append_line", '"index": 3', partial=True)
            failing_file = out / FRAMES
        with pytest.raises(RecordingError) as exc:
            w.write(frames[3])
        msg = str(exc.value)
        assert "disk full" in msg and str(failing_file) in msg and "3 complete frames" in msg
        monkeypatch.undo()
        with pytest.raises(RecordingError, match="earlier write failed"):
            w.write(frames[4])
    rec = open_recording(out)
    assert len(rec) == 3 and rec.problems == ()  # the partial line was cut back
    for k in range(3):
        assert_same_frame(rec.frame(k), frames[k])
    assert not (out / "color" / "000003.png").exists()
    assert rec.manifest["frame_count"] == 3


def test_never_overwrites_unless_asked(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    first = record(out, 2)
    with pytest.raises(RecordingError, match="already holds a recording") as exc:
        RecordingWriter(out, INFO)
    assert str(out) in str(exc.value) and "overwrite" in str(exc.value)
    assert len(open_recording(out)) == 2
    with RecordingWriter(out, INFO, overwrite=True) as w:
        w.write(synthetic_frame(7))
        # until the new one is closed, the old recording is still there, whole
        assert len(open_recording(out)) == 2
        assert_same_frame(open_recording(out).frame(1), first[1])
    rec = open_recording(out)
    assert len(rec) == 1 and rec.frame(0).meta["k"] == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]  # no staging or old copies left
    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.jpg").write_bytes(b"x")
    with pytest.raises(RecordingError, match="not empty and is not a recording"):
        RecordingWriter(other, INFO, overwrite=True)
    assert (other / "holiday.jpg").read_bytes() == b"x"
    (tmp_path / "afile").write_text("x")
    with pytest.raises(RecordingError, match="is a file"):
        RecordingWriter(tmp_path / "afile", INFO)
