"""Service configuration: TOML files in ``configs/`` validated with pydantic.

A file has a ``[server]`` table (where to listen, where to keep history) and a ``[source]``
table whose ``kind`` picks one of the source models below. Every model forbids unknown keys,
so a typo fails at start with the file, the key and what is allowed. :func:`source_spec`
turns a source model into the spec string ``device.open_source`` understands.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from device.base import SourceSpec


class ConfigError(ValueError):
    """A config file is missing, unparsable or has a wrong key or value; the message names them."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ServerConfig(_Model):
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    db: str = "depthruler.db"
    recordings: str = "recordings"  # the only folder the API records into
    history_max_gb: float | None = Field(None, gt=0, le=1e6)  # cap on saved frames; oldest unpinned deleted first
    token: str = ""
    insecure_no_token: bool = False  # serve on a non-loopback host without a token (anyone there can use it)
    allowed_hosts: tuple[str, ...] = ()  # extra Host names to answer (a DNS name of this machine)
    ring_size: int = Field(32, ge=2, le=4096)  # ~10 MB a 1280x720 frame
    max_frozen: int = Field(16, ge=1, le=1024)
    capture_fps: float = Field(15.0, gt=0, le=1000)
    reconnect_initial_s: float = Field(0.5, gt=0, le=60)
    reconnect_max_s: float = Field(10.0, gt=0, le=600)


class SimSource(_Model):
    kind: Literal["sim"] = "sim"
    scene: Literal["poster", "person", "doorway", "boxes", "table"] = "poster"
    distance: float = Field(4.0, gt=0.2, le=30.0)
    lighting: Literal["indoor", "mixed", "outdoor"] = "indoor"
    contention: float = Field(0.5, ge=0.0, le=0.5)
    quantization: float = Field(0.25, gt=0.0, le=1.0)
    seed: int = Field(0, ge=0)
    fps: float = Field(10.0, ge=0.0, le=120.0)
    width: int = Field(1280, ge=64, le=4096)
    height: int = Field(720, ge=64, le=4096)
    mode: Literal["model", "stereo"] = "model"


class OakSource(_Model):
    kind: Literal["oak"] = "oak"
    mxid: str = ""
    preset: Literal[
        "default", "fast_accuracy", "fast_density", "high_detail", "face", "robotics", "density", "accuracy"
    ] = "default"
    fps: float = Field(15.0, gt=0.0, le=120.0)
    width: int = Field(1280, ge=64, le=4056)
    height: int = Field(720, ge=64, le=3040)
    subpixel: bool = True
    lr_check: bool = True
    extended_disparity: bool = False


class SGBMOptions(_Model):
    num_disparities: int = Field(128, ge=16, le=1024, multiple_of=16)
    block_size: int = Field(5, ge=1, le=31)
    mode: Literal["sgbm", "sgbm_3way", "hh", "hh4"] = "sgbm_3way"
    uniqueness: int = Field(10, ge=0, le=100)
    speckle_window: int = Field(100, ge=0)
    speckle_range: int = Field(2, ge=0)
    wls: bool = False
    lr_confidence: bool = False
    fill_left_band: bool = True


# SGBMOptions field -> option name in the v4l2 spec (device/stereo_pair.py)
_SGBM_SPEC_KEYS = {"num_disparities": "ndisp", "block_size": "block"}


class V4L2Source(_Model):
    kind: Literal["v4l2"] = "v4l2"
    device: str = "/dev/video0"  # two nodes for a two-camera pair: "/dev/video0,/dev/video2"
    layout: Literal["side-by-side", "two-nodes"] = "side-by-side"
    calib: str = "configs/calib/stereo.json"
    width: int = Field(2560, ge=16, le=8192)
    height: int = Field(720, ge=16, le=8192)
    fps: float = Field(30.0, gt=0.0, le=240.0)
    fourcc: Literal["MJPG", "YUYV"] = "MJPG"
    scale: float = Field(1.0, gt=0.0, le=1.0)
    sgbm: SGBMOptions = SGBMOptions()


class ReplaySource(_Model):
    kind: Literal["replay"] = "replay"
    path: str = Field(min_length=1)
    loop: bool = True
    realtime: bool = True


SourceConfig = Annotated[Union[SimSource, OakSource, V4L2Source, ReplaySource], Field(discriminator="kind")]


class ServeConfig(_Model):
    server: ServerConfig = ServerConfig()
    source: SourceConfig | None = None


def _fmt(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def source_spec(source: SimSource | OakSource | V4L2Source | ReplaySource) -> str:
    """The ``open_source`` spec string of a validated source table (percent-encoded where a path or
    value holds ``?``, ``&``, ``%`` or spaces, so it parses back to the same values)."""
    if isinstance(source, SimSource):
        keys = ("distance", "lighting", "contention", "quantization", "seed", "fps", "width", "height", "mode")
        kind, target, params = "sim", source.scene, {k: getattr(source, k) for k in keys}
    elif isinstance(source, OakSource):
        params = {k: getattr(source, k) for k in ("preset", "fps", "subpixel", "lr_check", "extended_disparity")}
        params["size"] = f"{source.width}x{source.height}"
        kind, target = "oak", source.mxid
    elif isinstance(source, V4L2Source):
        params = {k: getattr(source, k) for k in ("layout", "calib", "fps", "fourcc", "scale")}
        params["size"] = f"{source.width}x{source.height}"
        params.update({_SGBM_SPEC_KEYS.get(k, k): v for k, v in source.sgbm.model_dump().items()})
        kind, target = "v4l2", source.device
    elif isinstance(source, ReplaySource):
        kind, target, params = "replay", source.path, {"loop": source.loop, "realtime": source.realtime}
    else:
        raise ConfigError(f"unknown source config {type(source).__name__}")
    return str(SourceSpec(kind, target, {k: _fmt(v) for k, v in params.items()}))


_SOURCE_MODELS: dict[str, type[BaseModel]] = {
    "sim": SimSource,
    "oak": OakSource,
    "v4l2": V4L2Source,
    "replay": ReplaySource,
}


def _model_at(loc: tuple[Any, ...]) -> type[BaseModel] | None:
    """The model class that owns the last key of an error location (to list its allowed keys)."""
    parts = [str(p) for p in loc[:-1]]
    model: type[BaseModel] | None = ServeConfig
    if parts[:1] == ["source"]:
        model = _SOURCE_MODELS.get(parts[1]) if len(parts) > 1 else None
        parts = parts[2:]
    for part in parts:
        field = model.model_fields.get(part) if model else None
        annotation = getattr(field, "annotation", None)
        if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
            return None
        model = annotation
    return model


def _describe(error: dict[str, Any]) -> str:
    loc = tuple(error["loc"])
    # A discriminated union puts the tag into the location (source.sim.distance); the file says source.distance.
    shown = [str(p) for i, p in enumerate(loc) if not (i == 1 and loc[0] == "source" and p in _SOURCE_MODELS)]
    key = ".".join(shown) or "(top level)"
    kind = error["type"]
    ctx = error.get("ctx") or {}
    if kind == "extra_forbidden":
        model = _model_at(loc)
        allowed = ", ".join(sorted(model.model_fields)) if model else "see configs/*.toml"
        return f"unknown key {key!r}; allowed keys here: {allowed}"
    if kind == "literal_error":
        return f"{key} = {error.get('input')!r} is not allowed; allowed values: {ctx.get('expected')}"
    if kind == "union_tag_invalid":
        return f"{key}: kind {ctx.get('tag')!r} is unknown; allowed kinds: {ctx.get('expected_tags')}"
    if kind == "union_tag_not_found":
        return f"{key}: add kind = one of {', '.join(repr(k) for k in _SOURCE_MODELS)}"
    return f"{key} = {error.get('input')!r}: {error['msg']}"


def parse_config(data: dict[str, Any], origin: str = "<config>") -> ServeConfig:
    """Validate an already-parsed TOML document; :class:`ConfigError` names ``origin``, keys and allowed values."""
    try:
        return ServeConfig.model_validate(data)
    except ValidationError as exc:
        lines = [_describe(e) for e in exc.errors()]
        raise ConfigError(f"{origin}: " + "; ".join(lines)) from None


def load_config(path: str | Path) -> ServeConfig:
    """Read and validate a TOML config file (see ``configs/``)."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{p}: config file not found; pick one of configs/*.toml or pass --source instead")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte {exc.start}: {exc.object[exc.start:exc.start + 1]!r}); save it as UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the config file ({exc.strerror or exc})") from None
    return parse_config(data, str(p))
