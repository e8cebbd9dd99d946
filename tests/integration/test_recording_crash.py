"""Kill a recording process mid-stream (SIGKILL, and Ctrl-C through the CLI): every complete frame survives."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from factories import assert_same_frame, record, synthetic_frame

from device.formats.recording import FRAMES, open_recording

ROOT = Path(__file__).resolve().parents[2]

WRITER_SCRIPT = """
import sys
sys.path[:0] = [{root!r}, {tests!r}]
from factories import SYNTH_INFO, synthetic_frame
from device.formats.recording import RecordingWriter
w = RecordingWriter({out!r}, SYNTH_INFO)
k = 0
while True:
    w.write(synthetic_frame(k, 320, 240))
    print(k, flush=True)
    k += 1
"""


def _wait_for_lines(path: Path, n: int, proc: subprocess.Popen, limit_s: float = 60.0) -> None:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if path.exists() and path.read_bytes().count(b"\n") >= n:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the recording process ended early: {proc.stderr.read() if proc.stderr else ''}")
        time.sleep(0.02)
    raise AssertionError(f"no {n} frames within {limit_s} s")


@pytest.mark.slow
@pytest.mark.parametrize("delay_s", [0.0, 0.037])
def test_sigkill_mid_stream_keeps_every_complete_frame(tmp_path: Path, delay_s: float) -> None:
    out = tmp_path / "rec"
    script = WRITER_SCRIPT.format(root=str(ROOT), tests=str(ROOT / "tests"), out=str(out))
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_lines(out / FRAMES, 8, proc)
        time.sleep(delay_s)  # land the kill at different points of a frame
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    printed = [int(x) for x in proc.stdout.read().split()]
    data = (out / FRAMES).read_bytes()
    parsed = 0
    for line in data.split(b"\n"):
        try:
            json.loads(line)
            parsed += 1
        except ValueError:
            pass
    rec = open_recording(out)
    # every frame the writer reported done is there, and every fully written line is a frame
    assert len(rec) >= max(len(printed), 8)  # 8 lines were complete before the kill; a frame may not be printed yet
    assert len(rec) == parsed
    assert rec.manifest["complete"] is False
    for k in range(len(rec)):
        assert_same_frame(rec.frame(k), synthetic_frame(k, 320, 240))


@pytest.mark.slow
def test_ctrl_c_stops_the_record_command_cleanly(tmp_path: Path) -> None:
    src = tmp_path / "src"
    record(src, 3)
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-c",
        "import sys, typer; from cli.recording import record; typer.run(record)",
        "--source",
        f"replay:{src}?loop=1",
        "--frames",
        "1000000",
        "--out",
        str(out),
    ]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for_lines(out / FRAMES, 5, proc)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "stopped by Ctrl-C" in stdout and str(out) in stdout
    rec = open_recording(out)
    assert rec.problems == () and rec.manifest["complete"] is True and rec.manifest["frame_count"] == len(rec) >= 5
    for k in range(len(rec)):
        assert_same_frame(rec.frame(k), synthetic_frame(k % 3))
