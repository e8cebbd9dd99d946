"""Sources of frames: real devices, recordings, imported datasets and the simulator.

``open_source(spec_or_config)`` imports a backend only when it is asked for, so ``import device``
stays fast and works without any SDK or hardware. The kinds, their config dataclasses and
Source classes are listed once, in :data:`device.base.BACKENDS`.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

from device.base import BACKENDS, Backend, Source, SourceBase, SourceInfo, SourceSpec, backend
from device.configs import from_table, spec_from_table
from device.errors import (
    CalibrationError,
    RecordingError,
    SourceDisconnected,
    SourceEnded,
    SourceError,
    SourceNotFound,
    SourceTimeout,
)


def _module(kind: str, shown: str = ""):
    return importlib.import_module(backend(kind, shown).module)


def source_config(spec: str | SourceSpec | Mapping[str, object]) -> object:
    """The config dataclass of a source: from a spec string (``"v4l2:/dev/video0?ndisp=64"``), a parsed
    SourceSpec or a TOML ``[source]`` table / API body (``{"kind": "v4l2", "device": "/dev/video0", "ndisp": 64}``).
    All go through the one parser (device.configs) and the kind's config dataclass, so they give equal
    configs with equal defaults; an unknown key or a bad value raises SourceError naming what is allowed."""
    if isinstance(spec, Mapping):
        return from_table(spec)
    parsed = spec if isinstance(spec, SourceSpec) else SourceSpec.parse(spec)
    return _module(parsed.kind, str(parsed)).config_from_spec(parsed)


def kind_of(config: object) -> str:
    """The registered kind whose config dataclass ``config`` is (SourceError if none is). A kind's module
    may be a package that defines the dataclass in one of its modules (``device.sources.bag.config``)."""
    cls = type(config)
    for kind, entry in BACKENDS.items():
        inside = cls.__module__ == entry.module or cls.__module__.startswith(entry.module + ".")
        if inside and entry.config == cls.__qualname__:
            return kind
    raise SourceError(f"{cls.__qualname__} is not the config of a registered source kind ({', '.join(BACKENDS)})")


def make_source(spec: str | SourceSpec | object) -> Source:
    """The source a spec string, a SourceSpec or a config dataclass (e.g. ``SimConfig(distance_m=6)``)
    describes, not yet opened."""
    config = spec if not isinstance(spec, (str, SourceSpec)) else source_config(spec)
    kind = kind_of(config)
    return getattr(_module(kind), BACKENDS[kind].source)(config)


def open_source(spec: str | SourceSpec | object) -> Source:
    """Open the source a spec or config names: ``with open_source("sim") as src: frame = src.read()``."""
    src = make_source(spec)
    src.open()
    return src


def list_devices() -> list[SourceInfo]:
    """Attached cameras: DepthAI devices, V4L2 nodes and USB ids (via pyusb)."""
    from device.discovery import list_devices as _list

    return _list()


__all__ = [
    "BACKENDS",
    "Backend",
    "CalibrationError",
    "RecordingError",
    "Source",
    "SourceBase",
    "SourceDisconnected",
    "SourceEnded",
    "SourceError",
    "SourceInfo",
    "SourceNotFound",
    "SourceSpec",
    "SourceTimeout",
    "kind_of",
    "list_devices",
    "make_source",
    "open_source",
    "source_config",
    "spec_from_table",
]
