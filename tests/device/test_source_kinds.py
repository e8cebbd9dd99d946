"""One description per source kind: a spec string and a TOML [source] table are two
spellings of the kind's one config dataclass, registered in device.BACKENDS next to its Source class."""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

import pytest

from device import BACKENDS, SourceError, SourceSpec, kind_of, make_source, source_config
from service.config import ConfigError, load_config

# kind -> (spec string, the same options as a TOML [source] table); every value differs from its default
CASES = {
    "sim": ("sim:boxes?distance=6.5&lighting=outdoor&seed=3&fps=0&width=640&height=360&noise_px=0.3",
            'kind = "sim"\nscene = "boxes"\ndistance = 6.5\nlighting = "outdoor"\nseed = 3\nfps = 0\n'
            'width = 640\nheight = 360\nnoise_px = 0.3\n'),
    "oak": ("oak:1844301011B546F500?preset=high_detail&fps=10&size=640x400&mono_width=1280&mono_height=800"
            "&search_timeout_ms=2500&subpixel=0&confidence_threshold=55&align=left",
            'kind = "oak"\nmxid = "1844301011B546F500"\npreset = "high_detail"\nfps = 10\nsize = "640x400"\n'
            'mono_width = 1280\nmono_height = 800\nsearch_timeout_ms = 2500\nsubpixel = false\n'
            'confidence_threshold = 55\nalign = "left"\n'),
    "v4l2": ("v4l2:/dev/video0,/dev/video2?calib=rig.json&size=1280x720&fps=15&fourcc=YUYV&ndisp=128&block=7&wls=1",
             'kind = "v4l2"\ndevice = ["/dev/video0", "/dev/video2"]\ncalib = "rig.json"\nsize = "1280x720"\n'
             'fps = 15\nfourcc = "YUYV"\nndisp = 128\nblock = 7\nwls = true\n'),
    "video": ("video:pair.mkv?layout=top-bottom&calib=stereo.yaml&loop=1&realtime=1&scale=0.5&ndisp=96",
              'kind = "video"\npath = "pair.mkv"\nlayout = "top-bottom"\ncalib = "stereo.yaml"\nloop = true\n'
              'realtime = true\nscale = 0.5\nndisp = 96\n'),
    "replay": ("replay:rec/desk?loop=1&realtime=1&speed=2&start=10",
               'kind = "replay"\npath = "rec/desk"\nloop = true\nrealtime = true\nspeed = 2\nstart = 10\n'),
    "middlebury": ("middlebury:data/Teddy?disparity=gt",
                   'kind = "middlebury"\npath = "data/Teddy"\ndisparity = "gt"\n'),
    "depthpng": ("depthpng:scans/desk?baseline=0.05&depth_scale=1000&fps=30&loop=1",
                 'kind = "depthpng"\npath = "scans/desk"\nbaseline = 0.05\ndepth_scale = 1000\nfps = 30\nloop = true\n'),
    "bag": ("bag:walk.bag?depth=/cam/depth&color=/cam/color&baseline=0.05&skew_ms=20&loop=1&start=2",
            'kind = "bag"\npath = "walk.bag"\ndepth = "/cam/depth"\ncolor = "/cam/color"\nbaseline = 0.05\n'
            'skew_ms = 20\nloop = true\nstart = 2\n'),
}
# kind -> (the least spec, the least table): everything else is the config dataclass's default
LEAST = {
    "sim": ("sim", 'kind = "sim"\n'),
    "oak": ("oak", 'kind = "oak"\n'),
    "v4l2": ("v4l2:/dev/video0", 'kind = "v4l2"\ndevice = "/dev/video0"\n'),
    "video": ("video:pair.mkv", 'kind = "video"\npath = "pair.mkv"\n'),
    "replay": ("replay:rec", 'kind = "replay"\npath = "rec"\n'),
    "middlebury": ("middlebury:Teddy", 'kind = "middlebury"\npath = "Teddy"\n'),
    "depthpng": ("depthpng:scans", 'kind = "depthpng"\npath = "scans"\n'),
    "bag": ("bag:walk.bag", 'kind = "bag"\npath = "walk.bag"\n'),
}


def from_toml(tmp_path: Path, table: str) -> object:
    path = tmp_path / "serve.toml"
    path.write_text("[source]\n" + table)
    return source_config(load_config(path).source)


def test_cases_cover_every_registered_kind():
    assert set(CASES) == set(BACKENDS) == set(LEAST)


@pytest.mark.parametrize("kind", sorted(BACKENDS))
def test_spec_and_toml_give_the_same_config(kind, tmp_path):
    entry = BACKENDS[kind]
    config_cls = getattr(importlib.import_module(entry.module), entry.config)
    spec, table = CASES[kind]
    config = source_config(spec)
    assert type(config) is config_cls and dataclasses.is_dataclass(config) and kind_of(config) == kind
    assert from_toml(tmp_path, table) == config
    least = source_config(LEAST[kind][0])
    assert from_toml(tmp_path, LEAST[kind][1]) == least  # same defaults both ways
    assert least != config  # the full case really sets something
    src = make_source(config)  # the registered Source class takes the config (not opened: no device here)
    assert type(src).__name__ == entry.source and not getattr(src, "is_open", False)


@pytest.mark.parametrize("kind", sorted(BACKENDS))
def test_unknown_key_is_refused_naming_the_kind(kind, tmp_path):
    with pytest.raises(SourceError, match=rf"(?i)\b{kind}\b.*\bbogus\b|\bbogus\b.*\b{kind}\b"):
        source_config(str(SourceSpec.parse(LEAST[kind][0])) + ("&" if "?" in LEAST[kind][0] else "?") + "bogus=1")
    path = tmp_path / "bad.toml"
    path.write_text("[source]\n" + LEAST[kind][1] + "bogus = 1\n")
    with pytest.raises(ConfigError) as err:
        load_config(path)
    message = str(err.value)
    assert str(path) in message and "bogus" in message and kind in message.lower(), message


# The drift the three hand-kept descriptions had (each failed before: the TOML model disagreed).


def test_v4l2_table_without_size_or_ndisp_gets_the_benchmarked_defaults(tmp_path):
    config = from_toml(tmp_path, 'kind = "v4l2"\ndevice = "/dev/video0"\ncalib = "rig.json"\n')
    assert (config.width, config.height, config.sgbm.num_disparities) == (1280, 480, 64)
    assert config == source_config("v4l2:/dev/video0?calib=rig.json")


def test_replay_loop_and_realtime_default_off_in_toml_as_in_specs(tmp_path):
    config = from_toml(tmp_path, 'kind = "replay"\npath = "rec"\n')
    assert (config.loop, config.realtime) == (False, False)
    assert config == source_config("replay:rec")


def test_oak_mono_size_and_search_timeout_are_settable_from_toml(tmp_path):
    config = from_toml(tmp_path, 'kind = "oak"\nmono_width = 1280\nmono_height = 800\nsearch_timeout_ms = 5000\n')
    assert (config.mono_width, config.mono_height, config.search_timeout_ms) == (1280, 800, 5000)


def test_oak_stereo_options_left_out_of_toml_keep_the_preset(tmp_path):
    config = from_toml(tmp_path, 'kind = "oak"\npreset = "high_detail"\n')
    assert (config.subpixel, config.lr_check, config.extended_disparity, config.confidence_threshold) == (None,) * 4
    shipped = source_config(load_config(Path(__file__).resolve().parents[2] / "configs" / "oak.toml").source)
    assert (shipped.subpixel, shipped.lr_check, shipped.extended_disparity) == (None, None, None)


@pytest.mark.parametrize("kind", ["middlebury", "depthpng", "video", "bag"])
def test_file_kinds_are_usable_from_toml(kind, tmp_path):
    assert kind_of(from_toml(tmp_path, CASES[kind][1])) == kind


def test_open_source_takes_a_config_object():
    from device import open_source
    from sim.source import SimConfig

    with open_source(SimConfig(scene="boxes", distance_m=3.0, fps=0, width=320, height=180)) as src:
        frame = src.read()
    assert frame.disparity.shape == (180, 320) and frame.meta["source"] == "sim"
    with pytest.raises(SourceError, match="not the config of a registered source kind"):
        make_source(object())
