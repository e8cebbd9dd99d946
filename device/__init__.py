"""Sources of frames: real devices, recordings, imported datasets and the simulator.

``open_source(spec)`` imports a backend only when its spec asks for it, so ``import device``
stays fast and works without any SDK or hardware.
"""

from __future__ import annotations

import importlib

from .base import Source, SourceBase, SourceInfo, SourceSpec
from .errors import (
    CalibrationError,
    RecordingError,
    SourceDisconnected,
    SourceEnded,
    SourceError,
    SourceNotFound,
    SourceTimeout,
)

# kind -> "module:factory"; the factory takes a SourceSpec and returns an unopened Source.
BACKENDS: dict[str, str] = {
    "sim": "sim.source:from_spec",
    "oak": "device.oak:from_spec",
    "v4l2": "device.stereo_pair:from_spec",
    "video": "device.video:from_spec",
    "replay": "device.recording:from_spec",
    "middlebury": "device.middlebury:from_spec",
    "depthpng": "device.depth_folder:from_spec",
    "bag": "device.bag:from_spec",
}


def make_source(spec: str | SourceSpec) -> Source:
    """The source a spec names, not yet opened."""
    parsed = spec if isinstance(spec, SourceSpec) else SourceSpec.parse(spec)
    target = BACKENDS.get(parsed.kind)
    if target is None:
        raise SourceNotFound(
            f"unknown source kind {parsed.kind!r} in {str(parsed)!r}; use one of: {', '.join(sorted(BACKENDS))}"
        )
    module_name, _, factory = target.partition(":")
    module = importlib.import_module(module_name)
    return getattr(module, factory)(parsed)


def open_source(spec: str | SourceSpec) -> Source:
    """Open the source a spec names: ``with open_source("sim") as src: frame = src.read()``."""
    src = make_source(spec)
    src.open()
    return src


def list_devices() -> list[SourceInfo]:
    """Attached cameras: DepthAI devices, V4L2 nodes and USB ids (via pyusb)."""
    from .discovery import list_devices as _list

    return _list()


__all__ = [
    "BACKENDS",
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
    "list_devices",
    "make_source",
    "open_source",
]
