"""The one protocol every source implements, and source specs (ARCHITECTURE.md "Sources")."""

from __future__ import annotations

from dataclasses import dataclass, field
from types import TracebackType
from typing import Protocol, runtime_checkable
from urllib.parse import parse_qsl, quote, unquote

from measure import Frame

from .errors import SourceError


@dataclass(frozen=True)
class SourceInfo:
    """What a source is: kind ("sim", "oak", "v4l2", "replay", "middlebury", "usb"), name, serial, size, fps."""

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
            raise SourceError(f"source spec {spec!r} names no kind; start it with one of sim, oak, v4l2, replay, middlebury, depthpng")
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

    def __str__(self) -> str:
        s = self.kind + (f":{quote(self.target, safe=_SAFE)}" if self.target else "")
        if self.params:
            # Percent-encoded where parse_qsl would read something else (&, =, +, %, #, spaces, ...).
            s += "?" + "&".join(f"{quote(k, safe=_SAFE)}={quote(v, safe=_SAFE)}" for k, v in self.params.items())
        return s
