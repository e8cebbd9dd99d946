"""The one protocol every source implements, source specs, and the registry of source kinds.

:data:`BACKENDS` is the one list of source kinds. Each kind has one config dataclass (the one
description of its options, defaults and checks) and one Source class built from it; a spec
string (``kind:target?key=value``) and a TOML ``[source]`` table are two spellings of the same
options, both parsed by the kind's ``config_from_spec`` (docs/design.md "Sources").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import TracebackType
from typing import Protocol, runtime_checkable
from urllib.parse import parse_qsl, quote, unquote

from measure import Frame

from device.errors import SourceError


# A frame's meta key for a zero-argument callable that returns the frame's image bit for bit (the
# simulator's: its render plus a crop of a fixed noise sheet). A holder of many frames (the service's
# ring) may drop the image and call it when the image is asked for; recordings do not store it.
REBUILD_IMAGE = "rebuild_image"


@dataclass(frozen=True)
class SourceInfo:
    """What a source is: kind (a :data:`BACKENDS` kind, or "usb" for an unrecognised USB camera), name, serial, size, fps."""

    kind: str
    name: str
    serial: str = ""
    width: int = 0
    height: int = 0
    fps: float = 0.0
    state: str = ""
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Source(Protocol):
    info: SourceInfo

    def open(self) -> None: ...

    def read(self, timeout_s: float = 1.0) -> Frame: ...

    def close(self) -> None: ...

    def __enter__(self) -> Source: ...

    def __exit__(self, *exc: object) -> None: ...


@runtime_checkable
class FrameAccess(Protocol):
    """A source of a fixed number of frames (a recording, a bag) that reads any of them directly."""

    def __len__(self) -> int: ...

    def frame(self, i: int) -> Frame: ...


class SourceBase:
    """Context-manager plumbing shared by all sources: ``with src: src.read()``."""

    info: SourceInfo

    @property
    def is_open(self) -> bool:
        return getattr(self, "_open", False)

    def open(self) -> None:
        self._open = True

    def close(self) -> None:
        self._open = False

    def __enter__(self):
        if not self.is_open:
            self.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


_TRUE = frozenset({"1", "true", "yes", "on"})
_FALSE = frozenset({"0", "false", "no", "off"})


def parse_flag(text: str) -> bool:
    """A yes/no source option: 1/0, true/false, yes/no, on/off (any case). Raises ValueError."""
    v = text.strip().lower()
    if v in _TRUE:
        return True
    if v in _FALSE:
        return False
    raise ValueError(f"{text!r} is not a yes/no (boolean) value (use 1/0, true/false)")


_SAFE = "/,:@.-_~"  # left as they are when a spec is printed: paths, device lists, sizes stay readable


@dataclass(frozen=True)
class SourceSpec:
    """A parsed spec string ``kind[:target][?key=value&...]``, e.g. ``sim:poster?distance=4``.

    Target, keys and values are percent-decoded (``replay:rec/a%3Fb`` is the folder ``rec/a?b``);
    ``str()`` encodes what would read otherwise, so a printed spec parses back to the same one.
    """

    kind: str
    target: str = ""
    params: dict[str, str] = field(default_factory=dict)

    @classmethod
    def parse(cls, spec: str) -> SourceSpec:
        if not isinstance(spec, str) or not spec.strip():
            raise SourceError("empty source spec; use e.g. 'sim', 'oak', 'v4l2:/dev/video0' or 'replay:DIR'")
        spec = spec.strip()
        head, _, query = spec.partition("?")
        kind, _, target = head.partition(":")
        try:
            params = dict(parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query)))
        except ValueError as exc:
            raise SourceError(f"cannot parse the options {query!r} of source spec {spec!r}; write key=value&key=value") from exc
        if not kind.strip():
            raise SourceError(f"source spec {spec!r} names no kind; start it with one of {', '.join(BACKENDS)}")
        return cls(kind=kind.strip().lower(), target=unquote(target), params=params)

    def check_keys(self, allowed: tuple[str, ...]) -> None:
        """Raise SourceError naming the options of this spec that its kind does not know."""
        unknown = set(self.params) - set(allowed)
        if unknown:
            raise SourceError(f"unknown {self.kind} option(s) {', '.join(sorted(unknown))}; use {', '.join(allowed)}")

    def flag(self, key: str, default: bool) -> bool:
        """The yes/no option ``key`` (a blank value is no), or ``default`` when it is absent."""
        if key not in self.params:
            return default
        if not self.params[key].strip():
            return False
        try:
            return parse_flag(self.params[key])
        except ValueError:
            raise SourceError(f"{key}={self.params[key]!r} is not a yes/no value; write {key}=1 or {key}=0") from None

    def number(self, key: str) -> float | None:
        """The numeric option ``key``, or None when it is absent."""
        if key not in self.params:
            return None
        try:
            return float(self.params[key])
        except ValueError:
            raise SourceError(f"{self.kind} option {key}={self.params[key]!r} must be a number") from None

    def __str__(self) -> str:
        s = self.kind + (f":{quote(self.target, safe=_SAFE)}" if self.target else "")
        if self.params:
            # Percent-encoded where parse_qsl would read something else (&, =, +, %, #, spaces, ...).
            s += "?" + "&".join(f"{quote(k, safe=_SAFE)}={quote(v, safe=_SAFE)}" for k, v in self.params.items())
        return s


@dataclass(frozen=True)
class Backend:
    """Where a source kind lives: ``module`` defines the config dataclass ``config``, the Source class
    ``source`` (built from one config) and ``config_from_spec(SourceSpec) -> config``. ``target`` is the
    TOML key that holds what a spec string names after the colon (a scene, a device, a path)."""

    module: str
    config: str
    source: str
    target: str


# The device layer's own source kinds. Modules are imported when a kind is used, so ``import device``
# needs no SDK (depthai, rosbags) and no camera.
BUILTIN_BACKENDS: dict[str, Backend] = {
    "oak": Backend("device.sources.oak", "OakConfig", "OakSource", "mxid"),
    "v4l2": Backend("device.sources.stereo_pair", "StereoPairConfig", "StereoPairSource", "device"),
    "video": Backend("device.sources.video", "VideoConfig", "VideoSource", "path"),
    "replay": Backend("device.formats.recording.replay", "ReplayConfig", "ReplaySource", "path"),
    "middlebury": Backend("device.sources.middlebury", "MiddleburyConfig", "MiddleburySource", "path"),
    "depthpng": Backend("device.sources.depth_folder", "DepthFolderConfig", "DepthFolderSource", "path"),
    "bag": Backend("device.sources.bag", "BagConfig", "BagSource", "path"),
}
ENTRY_POINT_GROUP = "depthruler.sources"


class _Registry(Mapping[str, Backend]):
    """Every source kind: the built-in ones, and those that packages above ``device`` (the simulator,
    a package of your own) register under the entry-point group ``depthruler.sources`` as a
    :class:`Backend` object. An entry point is loaded the first time its kind is looked up."""

    def __init__(self, builtin: dict[str, Backend]) -> None:
        self._builtin = builtin
        self._loaded: dict[str, Backend] = {}
        self._points: dict | None = None

    def _entry_points(self) -> dict:
        if self._points is None:
            from importlib.metadata import entry_points

            self._points = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name not in self._builtin}
        return self._points

    def __getitem__(self, kind: str) -> Backend:
        if kind in self._builtin:
            return self._builtin[kind]
        if kind not in self._loaded:
            ep = self._entry_points()[kind]  # KeyError for an unknown kind, as a Mapping must
            entry = ep.load()
            if not isinstance(entry, Backend):
                raise SourceError(f"entry point {ep.value} of source kind {kind!r} is not a device.base.Backend")
            self._loaded[kind] = entry
        return self._loaded[kind]

    def __iter__(self):
        return iter([*self._entry_points(), *self._builtin])

    def __len__(self) -> int:
        return len(self._builtin) + len(self._entry_points())


# The one list of source kinds (lookups by kind; iteration lists every kind).
BACKENDS: Mapping[str, Backend] = _Registry(BUILTIN_BACKENDS)


def backend(kind: str, shown: str = "") -> Backend:
    """The registry entry of ``kind``; SourceNotFound lists the kinds there are."""
    from device.errors import SourceNotFound

    found = BACKENDS.get(kind)
    if found is None:
        where = f" in {shown!r}" if shown else ""
        raise SourceNotFound(f"unknown source kind {kind!r}{where}; use one of: {', '.join(sorted(BACKENDS))}")
    return found
