"""`depthruler measure` headless on a recording, and `serve`'s source resolution."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from typer.testing import CliRunner

from device import SourceInfo
from device.formats.recording import RecordingWriter
from cli.main import app
from factories import SMALL_H, SMALL_W, WALL_DISP, wall_frame, wall_length

# serve's default port 8000 held meanwhile: none of these depends on it (tests/integration/test_busy_default_port.py)
pytestmark = pytest.mark.usefixtures("port_8000_held")

W, H, DISP = SMALL_W, SMALL_H, WALL_DISP


@pytest.fixture
def recording(tmp_path):
    """Three frames of a wall at 2, 1 and 0.667 m (disparity 15, 30, 45 px)."""
    out = tmp_path / "rec"
    with RecordingWriter(out, SourceInfo(kind="plane", name="Fake plane", width=W, height=H, fps=30.0)) as rec:
        for i in range(3):
            f = wall_frame(i)
            rec.write(replace(f, disparity=np.full((H, W), DISP * (i + 1), np.float32)))
    return out


def test_measure_on_named_frame_of_recording(recording):
    p1, p2 = (40.0, 30.0), (280.0, 200.0)
    runner = CliRunner()
    for n in (0, 2):
        result = runner.invoke(
            app, ["measure", f"replay:{recording}", "--p1", "40,30", "--p2", "280,200", "--frame", str(n), "--method", "basic", "--json"]
        )
        assert result.exit_code == 0, result.output
        out = json.loads(result.stdout)
        assert out["frame"] == n and out["method"] == "basic"
        assert out["distance_m"] == pytest.approx(wall_length(p1, p2) / (n + 1), rel=1e-3)  # 1/64 px disparity steps
    text = runner.invoke(app, ["measure", f"replay:{recording}", "--p1", "40,30", "--p2", "280,200", "--method", "basic"])
    assert text.exit_code == 0 and "distance " in text.stdout and "method basic" in text.stdout
    assert f"distance {wall_length(p1, p2):.4f} m" in text.stdout


def test_measure_reads_the_named_frame_of_a_recording_directly(recording):
    """`--frame N` reads frame N itself: a damaged earlier frame neither shifts it nor stops it, a damaged N is an error."""
    (recording / json.loads((recording / "frames.jsonl").read_text().splitlines()[0])["files"]["disparity"]).write_bytes(b"not a png")
    p1, p2 = (40.0, 30.0), (280.0, 200.0)
    args = ["--p1", "40,30", "--p2", "280,200", "--method", "basic", "--json"]
    ok = CliRunner().invoke(app, ["measure", f"replay:{recording}", "--frame", "2", *args])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.stdout)["distance_m"] == pytest.approx(wall_length(p1, p2) / 3, rel=1e-3)
    bad = CliRunner().invoke(app, ["measure", f"replay:{recording}", "--frame", "0", *args])
    assert bad.exit_code == 1 and "frame 0" in bad.output


@pytest.mark.parametrize(
    "args, fragment, code",
    [
        (["--p1", "40;30", "--p2", "280,200"], "X,Y", 2),
        (["--p1", "nan,30", "--p2", "280,200"], "finite", 2),
        (["--p1", "40,30", "--p2", "900,200"], "outside", 1),
        (["--p1", "40,30", "--p2", "280,200", "--method", "magic"], "method", 2),
        (["--p1", "40,30", "--p2", "280,200", "--frame", "7"], "frame 7", 1),
    ],
)
def test_measure_bad_input(recording, args, fragment, code):
    result = CliRunner().invoke(app, ["measure", f"replay:{recording}", *args])
    assert result.exit_code == code, result.output
    assert fragment in result.output


def test_measure_unknown_source():
    result = CliRunner().invoke(app, ["measure", "kinect:0", "--p1", "1,1", "--p2", "5,5"])
    assert result.exit_code == 1 and "unknown source kind" in result.output


def test_auto_source_falls_back_to_simulator(monkeypatch):
    import device

    from cli import serve as cli_serve

    monkeypatch.setattr(device, "list_devices", lambda: [SourceInfo(kind="v4l2", name="webcam")])
    assert cli_serve.first_oak() is None
    monkeypatch.setattr(device, "list_devices", lambda: [SourceInfo(kind="oak", name="OAK-D", extra={"spec": "oak:18443"})])
    assert cli_serve.first_oak() == "oak:18443"

    def broken():
        raise RuntimeError("libusb missing")

    monkeypatch.setattr(device, "list_devices", broken)
    assert cli_serve.first_oak() is None


def _depth_view_figures(spec: str) -> tuple[float, float]:
    """(share of pixels with depth, share of neighbouring pixel pairs that change: one has depth and the
    other not, or their disparities differ by more than 0.5 px) of the first frame of ``spec``."""
    from device import open_source

    with open_source(spec) as src:
        d = src.read(5.0).disparity
    changes = []
    for a, b in ((d[:, :-1], d[:, 1:]), (d[:-1], d[1:])):
        va, vb = np.isfinite(a), np.isfinite(b)
        changes.append(((va != vb) | (va & vb & (np.abs(np.where(va & vb, a - b, 0.0)) > 0.5))).mean())
    return float(np.isfinite(d).mean()), float(np.mean(changes))


def test_serve_without_a_camera_shows_surfaces_in_the_depth_view():
    """With no camera `serve` shows the simulator (``DEMO_SIM``); its depth view read as static (the stress
    profile: a quarter of the pixels without depth, a fifth of neighbouring pairs changing colour)."""
    from cli import serve as cli_serve

    valid, changes = _depth_view_figures(cli_serve.DEMO_SIM)
    assert valid >= 0.9 and changes <= 0.1, (valid, changes)
    stress_valid, stress_changes = _depth_view_figures("sim")  # what the evaluations use, unchanged
    assert stress_valid < 0.8 and stress_changes > 0.2, (stress_valid, stress_changes)


def test_auto_source_asks_depthai_in_a_child_process():
    """Without a camera the server gets the simulator, and DepthAI (about 190 MB resident) is never
    loaded into it: discovery ran in a child."""
    import subprocess
    import sys

    code = "import sys; from cli.serve import auto_source; s = auto_source(); print(s, 'depthai' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    from cli.serve import DEMO_SIM

    assert out.stdout.split()[-2:] == [DEMO_SIM, "False"], out.stdout + out.stderr


def test_serve_on_a_busy_port_says_so_before_starting(tmp_path):
    import socket

    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        result = CliRunner().invoke(app, ["serve", "--source", "sim", "--port", str(port), "--db", str(tmp_path / "b.db")])
    assert result.exit_code == 2
    assert f"port {port} on 127.0.0.1 is already in use" in result.output and "open http" not in result.output
    assert not (tmp_path / "b.db").exists()  # nothing was started or written
    args = ["serve", "--source", "sim", "--host", "no-such-host.invalid", "--token", "t", "--db", str(tmp_path / "b.db")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "cannot resolve --host 'no-such-host.invalid'" in result.output


def test_serve_refuses_an_exposed_host_without_a_token_whatever_the_port(tmp_path, monkeypatch):
    """The token rule comes first: a busy port (8000 held by anyone) does not change the answer."""
    import socket

    import uvicorn

    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: pytest.fail("started"))
    monkeypatch.delenv("DEPTHRULER_TOKEN", raising=False)
    with socket.create_server(("0.0.0.0", 0)) as busy:
        port = busy.getsockname()[1]
        result = CliRunner().invoke(app, ["serve", "--source", "sim", "--host", "0.0.0.0", "--port", str(port), "--db", str(tmp_path / "o.db")])
    assert result.exit_code == 2 and "--insecure-no-token" in result.output and "already in use" not in result.output


def test_serve_flags_override_config(tmp_path, monkeypatch):
    import uvicorn
    from fastapi.testclient import TestClient
    from server_process import free_port

    calls = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: calls.update(app=app, **kw))
    monkeypatch.setenv("DEPTHRULER_TOKEN", "tok")
    cfg = tmp_path / "c.toml"
    port = free_port()
    cfg.write_text(f'[server]\nport = 9100\ndb = "{tmp_path / "cfg.db"}"\n[source]\nkind = "replay"\npath = "/nowhere"\n')
    result = CliRunner().invoke(
        app, ["serve", "--config", str(cfg), "--host", "0.0.0.0", "--port", str(port), "--source", "kinect:0"]
    )
    assert result.exit_code == 0, result.output
    assert calls["host"] == "0.0.0.0" and calls["port"] == port
    assert "source kinect:0" in result.output  # --source beats the file's [source]
    assert (tmp_path / "cfg.db").exists()  # the file's db, not overridden
    with TestClient(calls["app"]) as c:
        assert c.get("/api/source").status_code == 401
        assert c.get("/api/source", headers={"Authorization": "Bearer tok"}).json()["spec"] == "kinect:0"
    result = CliRunner().invoke(app, ["serve", "--source", "sim", "--host", "0.0.0.0", "--token", "", "--db", str(tmp_path / "o.db")])
    assert result.exit_code == 2 and "--insecure-no-token" in result.output  # exposed needs a token


def test_measure_takes_a_bare_recording_folder(recording):
    """`replay` and `batch` take a recording folder as it is; `measure` does too (it once said "unknown source kind")."""
    args = ["--p1", "40,30", "--p2", "280,200", "--frame", "1", "--method", "basic", "--json"]
    bare = CliRunner().invoke(app, ["measure", str(recording), *args])
    spec = CliRunner().invoke(app, ["measure", f"replay:{recording}", *args])
    assert bare.exit_code == 0, bare.output
    assert json.loads(bare.stdout)["distance_m"] == json.loads(spec.stdout)["distance_m"] == pytest.approx(wall_length((40, 30), (280, 200)) / 2, rel=1e-3)
    looped = CliRunner().invoke(app, ["measure", f"{recording}?loop=1", *args])  # options stay the replay's
    assert looped.exit_code == 0 and json.loads(looped.stdout)["frame"] == 1
    missing = CliRunner().invoke(app, ["measure", str(recording / "nope"), *args])
    assert missing.exit_code == 1 and "is no source kind and no existing file or folder" in missing.output


def test_measure_refuses_a_negative_timeout(recording):
    res = CliRunner().invoke(app, ["measure", f"replay:{recording}", "--p1", "40,30", "--p2", "280,200", "--timeout", "-1"])
    assert res.exit_code == 2 and "--timeout" in res.output and "0.01" in res.output


def test_measure_text_says_when_there_is_no_basic_estimate(tmp_path):
    """A click with no depth within the window: robust measures along its line, basic has none; the text said "nan m"."""
    out = tmp_path / "hole"
    frame = wall_frame(0)
    holed = frame.disparity.copy()
    holed[20:41, 30:51] = np.nan  # no depth within the 5 px window around (40, 30)
    with RecordingWriter(out, SourceInfo(kind="plane", name="Fake plane", width=W, height=H, fps=30.0)) as rec:
        rec.write(replace(frame, disparity=holed))
    res = CliRunner().invoke(app, ["measure", f"replay:{out}", "--p1", "40,30", "--p2", "280,200"])
    assert res.exit_code == 0, res.output
    assert "nan" not in res.stdout and "basic estimate: none (no depth within the window at an end point)" in res.stdout
    assert f"distance {wall_length((40, 30), (280, 200)):.2f}" in res.stdout


def test_export_warns_about_measurements_it_cannot_place(recording, tmp_path):
    base = {"distance_m": 1.0, "p1": [40, 30], "p2": [280, 200]}
    meas = [{**base, "frame_index": 1, "source": f"replay:{recording}"},  # on this recording: no warning
            {**base},  # no source, no frame: drawn on frame 0
            {**base, "frame_index": 2, "source": str(tmp_path / "other-rec")}]  # fmt: skip
    (tmp_path / "other-rec").mkdir()
    (tmp_path / "other-rec" / "manifest.json").write_text("{}")
    (tmp_path / "m.json").write_text(json.dumps(meas))
    res = CliRunner().invoke(app, ["export", str(recording), "--mcap", str(tmp_path / "o.mcap"), "--measurements", str(tmp_path / "m.json")])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "warning: 1 measurement(s) (1) name no frame_index: they are drawn on frame 0" in text
    assert f"warning: 1 measurement(s) (2) were made on {tmp_path / 'other-rec'}, not on {recording}" in text
    assert "(0)" not in text and (tmp_path / "o.mcap").stat().st_size > 0


def test_saved_frames_and_checks_beside_a_database_are_ignored_by_git():
    """The service writes <db stem>-frames/ and <db stem>-checks.jsonl beside its database (depthruler-frames/ by default)."""
    import shutil
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    if shutil.which("git") is None or not (root / ".git").exists():
        pytest.skip("not a git checkout")
    names = ["depthruler.db", "depthruler-frames/0a1b.frame", "depthruler-checks.jsonl", "depthruler-checks/0a1b.png",
             "data/station-frames/x.frame", "data/station-checks.jsonl"]
    res = subprocess.run(["git", "-C", str(root), "check-ignore", "--no-index", *names], capture_output=True, text=True)
    assert res.stdout.split() == names


def test_help_defaults_come_from_the_option_definitions():
    """No option's help repeats its default in prose (it drifts from the definition): typer shows the real one."""
    import re

    import typer.main

    def commands(cmd, path=()):
        for name, sub in getattr(cmd, "commands", {}).items():
            yield from commands(sub, (*path, name))
        if not getattr(cmd, "commands", None):
            yield path, cmd

    seen = 0
    for path, cmd in commands(typer.main.get_command(app)):
        for param in cmd.params:
            seen += 1
            assert not re.search(r"\(default\b|\bdefault:|\bdefault \$?[\d/.]", param.help or "", re.I), (path, param.name, param.help)
    assert seen > 80


def test_serve_and_measure_help_show_the_settings_defaults_and_the_core_s_choices():
    from typer.testing import CliRunner

    from measure import MAX_FRAMES, METHODS
    from service.config import ServerConfig

    server = ServerConfig()
    text = " ".join(CliRunner().invoke(app, ["serve", "--help"], env={"COLUMNS": "400"}).output.split())
    for value in (server.host, server.port, server.db, server.ring_size, server.header_timeout_s, server.body_timeout_s,
                  server.keep_alive_s, server.max_connections):
        assert f"config's or {value}" in text, value
    text = " ".join(CliRunner().invoke(app, ["measure", "--help"], env={"COLUMNS": "400"}).output.split())
    assert f"One of {', '.join(METHODS)}; left out, robust." in text and f"(at most {MAX_FRAMES})" in text
    assert "{method" not in text and "{max_frames}" not in text


def test_segment_text_never_prints_nan_for_a_pooled_answer_without_sigma(recording):
    """A pooled answer whose sigmas are unknown: the text said "nan m on the newest frame alone, nanx narrower"."""
    from cli.shapes import segment_text
    from device import open_source
    from measure import measure_sequence

    with open_source(f"replay:{recording}") as src:
        frames = [src.read(), src.read()]
    pooled = measure_sequence(frames, (40, 30), (280, 200))
    unknown = replace(pooled, uncertainty_m=math.nan, single_frame_uncertainty_m=math.nan, interval_m=(math.nan, math.nan))
    text = "\n".join(segment_text(unknown, 2, 1))
    assert "nan" not in text.lower() and "inf" not in text.lower()
    assert "(uncertainty unknown)" in text and "one sigma unknown on the newest frame alone" in text
    assert "narrower" in "\n".join(segment_text(pooled, 2, 1))
