"""Service configuration: TOML files in ``configs/`` validated with pydantic.

A file has a ``[server]`` table (where to listen, where to keep history) and a ``[source]``
table whose ``kind`` picks a registered source kind (``device.BACKENDS``). The source table's
keys are the kind's spec options (``kind = "v4l2"``, ``device = "/dev/video0"``, ``ndisp = 64``
is ``v4l2:/dev/video0?ndisp=64``), parsed into the kind's config dataclass by the same parser as
a ``--source`` string, so both give the same defaults. Unknown keys fail at start with the file,
the key and what is allowed.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from service.connections import ConnectionLimits
from service.guard import MAX_BODY_BYTES

_LIMITS = ConnectionLimits()


class ConfigError(ValueError):
    """A config file is missing, unparsable or has a wrong key or value; the message names them."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ServerConfig(_Model):
    """How the service runs: the ``[server]`` table of a config file, ``depthruler serve``'s flags,
    and the one settings object ``service.app.create_app`` takes (these defaults are the only ones)."""

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    db: str = "depthruler.db"
    recordings: str | None = None  # the only folder the API records into; None: recordings/ next to db
    history_max_gb: float | None = Field(None, gt=0, le=1e6)  # cap on saved frames; oldest unpinned deleted first
    token: str = ""
    insecure_no_token: bool = False  # serve on a non-loopback host without a token (anyone there can use it)
    allowed_hosts: tuple[str, ...] = ()  # extra Host names to answer (a DNS name of this machine)
    ring_size: int = Field(32, ge=2, le=4096)  # frames in memory: width x height x 7 bytes each
    max_frozen: int = Field(64, ge=1, le=1024)  # frames frozen at once (memory); beyond, the least recently used is released
    freeze_ttl_s: float = Field(60.0, gt=0, le=86_400)  # a frozen frame nobody used for this long is released
    measure_workers: int = Field(0, ge=0, le=256)  # measurements at once; 0: the CPU count
    measure_queue: int = Field(8, ge=0, le=100_000)  # measurements waiting for a worker; 429 beyond
    # The measurement threads' niceness above the server's (Linux): when the cores are busy, the live
    # view, the long-polls and health are served first (docs/decisions/measure-pool.md).
    measure_nice: int = Field(10, ge=0, le=19)
    capture_fps: float = Field(15.0, gt=0, le=1000)
    reconnect_initial_s: float = Field(0.5, gt=0, le=60)
    reconnect_max_s: float = Field(10.0, gt=0, le=600)
    keep_viewed: int = Field(8, ge=0, le=1024)  # frames handed to the page kept beyond the ring (it may freeze them)
    max_waiters: int = Field(64, ge=1, le=100_000)  # concurrent long-polls; 429 beyond
    max_body_bytes: int = Field(MAX_BODY_BYTES, ge=1024, le=1 << 30)
    # Connection limits (service.connections): seconds to the end of a request's headers, and of its body;
    # idle keep-alive; connections at once (fewer when the open-files limit is lower); descriptors kept for storage.
    header_timeout_s: float = Field(_LIMITS.header_timeout_s, gt=0, le=3600)
    body_timeout_s: float = Field(_LIMITS.body_timeout_s, gt=0, le=3600)
    keep_alive_s: float = Field(_LIMITS.keep_alive_s, gt=0, le=3600)
    max_connections: int = Field(_LIMITS.max_connections, ge=1, le=1_000_000)
    reserved_fds: int = Field(_LIMITS.reserved_fds, ge=64, le=1_000_000)

    @property
    def history_max_bytes(self) -> int | None:
        return int(round(self.history_max_gb * 1e9)) if self.history_max_gb else None

    @property
    def limits(self) -> ConnectionLimits:
        return ConnectionLimits(self.header_timeout_s, self.body_timeout_s, self.keep_alive_s, self.max_connections, self.reserved_fds)

    @property
    def recordings_dir(self) -> Path:
        return Path(self.recordings) if self.recordings else Path(self.db).resolve().parent / "recordings"


class ServeConfig(_Model):
    server: ServerConfig = ServerConfig()
    # The [source] table as the spec string it means (device.spec_from_table), parsed by the one parser
    # (device.configs): the table and a --source string are two spellings of the kind's config dataclass.
    source: str | None = None


def _describe(error: Any) -> str:
    loc = tuple(error["loc"])
    key = ".".join(str(p) for p in loc) or "(top level)"
    if error["type"] == "extra_forbidden":
        model = ServerConfig if loc[:1] == ("server",) and len(loc) == 2 else ServeConfig
        return f"unknown key {key!r}; allowed keys here: {', '.join(sorted(model.model_fields))}"
    return f"{key} = {error.get('input')!r}: {error['msg']}"


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def allowed_range(field: str) -> str:
    """The values :class:`ServerConfig` takes for the number ``field`` in words, from its Field bounds:
    ``"from 1 to 65535"``, ``"above 0, at most 3600"``, ``"at least 2"``."""
    import annotated_types as at

    lo = hi = None
    for m in ServerConfig.model_fields[field].metadata:
        if isinstance(m, at.Ge):
            lo = ("from", m.ge)
        elif isinstance(m, at.Gt):
            lo = ("above", m.gt)
        elif isinstance(m, at.Le):
            hi = ("at most", m.le)
        elif isinstance(m, at.Lt):
            hi = ("below", m.lt)
    if lo and hi and lo[0] == "from" and hi[0] == "at most":
        return f"from {_number(lo[1])} to {_number(hi[1])}"
    if lo and lo[0] == "from":
        lo = ("at least", lo[1])
    return ", ".join(f"{word} {_number(v)}" for word, v in (b for b in (lo, hi) if b)) or "of any size"


def describe_validation(exc: ValidationError, names: dict[str, str] | None = None) -> str:
    """One line for a :class:`ServerConfig` ValidationError: each bad key (spelt as ``names`` maps it,
    e.g. to its command-line flag), the value given and what is allowed."""
    parts = []
    for e in exc.errors():
        key = ".".join(str(p) for p in e["loc"])
        shown = (names or {}).get(key, key)
        if key in ServerConfig.model_fields and e["type"].startswith(("greater_than", "less_than")):
            parts.append(f"{shown} {e.get('input')!r} is out of range; give a value {allowed_range(key)}")
        else:
            parts.append(f"{shown} {e.get('input')!r}: {e['msg']}")
    return "; ".join(parts)


def source_table_spec(table: object, origin: str = "<config>") -> str:
    """The spec string of a ``[source]`` table, after the kind's parser accepted it (ConfigError names
    ``origin``, the kind and what is allowed)."""
    from device import SourceError, spec_from_table

    if not isinstance(table, dict):
        raise ConfigError(f"{origin}: source must be a table ([source] with kind = ...), not {table!r}")
    try:
        text = str(spec_from_table(table))  # parsed into the kind's config, written back as its spec
    except (SourceError, ValueError) as exc:  # ValueError: a config dataclass's own check
        raise ConfigError(f"{origin}: source: {exc}") from None
    return text


def parse_config(data: dict[str, Any], origin: str = "<config>") -> ServeConfig:
    """Validate an already-parsed TOML document; :class:`ConfigError` names ``origin``, keys and allowed values."""
    rest = {k: v for k, v in data.items() if k != "source"}
    try:
        cfg = ServeConfig.model_validate(rest)
    except ValidationError as exc:
        lines = [_describe(e) for e in exc.errors()]
        raise ConfigError(f"{origin}: " + "; ".join(lines)) from None
    if "source" not in data:
        return cfg
    return cfg.model_copy(update={"source": source_table_spec(data["source"], origin)})


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
