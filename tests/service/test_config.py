"""Config files: every shipped TOML validates, wrong keys/values fail naming file, key and allowed values."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from device import SourceSpec, make_source
from cli.main import app
from device import source_config
from service.config import ConfigError, load_config, parse_config

# serve's default port 8000 held meanwhile: none of these depends on it (tests/integration/test_busy_default_port.py)
pytestmark = pytest.mark.usefixtures("port_8000_held")

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name, kind", [("sim.toml", "sim"), ("oak.toml", "oak"), ("v4l2-sbs.toml", "v4l2"), ("replay.toml", "replay")])
def test_shipped_configs_validate(name, kind):
    cfg = load_config(CONFIGS / name)
    assert cfg.server.host == "127.0.0.1"
    spec = SourceSpec.parse(cfg.source)
    assert spec.kind == kind
    src = make_source(spec)  # the backend accepts every option the config writes (not opened: no device here)
    assert not getattr(src, "is_open", False)


def test_sim_table_carries_every_parameter():
    cfg = parse_config({"source": {"kind": "sim", "scene": "boxes", "distance": 6.5, "lighting": "outdoor", "seed": 3, "fps": 0}})
    spec = SourceSpec.parse(cfg.source)
    assert spec.target == "boxes"
    assert spec.params == {"distance": "6.5", "lighting": "outdoor", "seed": "3", "fps": "0"}
    config = source_config(spec)
    assert (config.scene, config.distance_m, config.lighting, config.seed, config.fps) == ("boxes", 6.5, "outdoor", 3, 0.0)


def test_sim_config_opens_the_simulator():
    from device import open_source

    cfg = load_config(CONFIGS / "sim.toml")
    with open_source(cfg.source) as src:
        frame = src.read()
    assert frame.meta["source"] == "sim" and frame.disparity.shape == (720, 1280)
    assert frame.meta["truth"].target.startswith("poster")


def test_oak_table_uses_backend_option_names():
    cfg = parse_config({"source": {"kind": "oak", "mxid": "1844301", "preset": "high_detail", "size": "640x400"}})
    spec = SourceSpec.parse(cfg.source)
    assert spec.target == "1844301" and spec.params == {"preset": "HIGH_DETAIL", "size": "640x400"}


@pytest.mark.parametrize(
    "text, fragments",
    [
        ('[source]\nkind = "sim"\nlighting = "sunny"\n', ["source:", "lighting='sunny'", "indoor", "outdoor"]),
        ('[source]\nkind = "sim"\nscnee = "poster"\n', ["source:", "'scnee'", "distance"]),
        ('[server]\nprot = 8000\n', ["server.prot", "port"]),
        ('[server]\nport = 70000\n', ["server.port", "70000"]),
        ('[source]\nkind = "kinect"\n', ["'kinect'", "oak", "sim"]),
        ('[source]\nscene = "poster"\n', ["source", "kind"]),
        ('[source]\nkind = "v4l2"\nndisp = 100\n', ["source:", "ndisp=100", "16"]),
        ('[source]\nkind = "v4l2"\n[source.sgbm]\nndisp = 64\n', ["source:", "sgbm", "flat"]),
        ('[source]\nkind = "replay"\n', ["source:", "replay:path"]),
        ("[source\n", ["not valid TOML"]),
    ],
)
def test_bad_config_names_file_key_and_allowed(tmp_path, text, fragments):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    message = str(err.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message


def test_missing_file():
    with pytest.raises(ConfigError, match="not found"):
        load_config("configs/nope.toml")


def test_parse_defaults():
    cfg = parse_config({})
    assert cfg.source is None and cfg.server.port == 8000 and cfg.server.ring_size == 32


def test_serve_fails_at_start_on_bad_config(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('[source]\nkind = "sim"\nlighting = "dusk"\n')
    result = CliRunner().invoke(app, ["serve", "--config", str(path)])
    assert result.exit_code == 2
    assert "lighting" in result.output and "mixed" in result.output and str(path) in result.output
