"""Option metadata on config dataclasses: each option's spellings, bounds, unit and help, written once.

A field declared with :func:`option` carries an :class:`Opt` in ``metadata["option"]``. From it:

1. :func:`check` validates an instance (the dataclass's ``__post_init__`` calls it) and raises the
   caller's typed error naming the option, the value and what is allowed;
2. :func:`describe` gives the JSON-ready description the API (``GET /api/options``), the manual's
   option tables and the CLI help are made from;
3. ``device.configs`` parses spec strings, TOML tables and API bodies into the dataclass by it.

Bounds are in the option's unit; ``min_open``/``max_open`` exclude the bound itself. No I/O here.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np


@dataclasses.dataclass(frozen=True)
class Opt:
    """What one option is: ``key`` (its spelling in specs, TOML and API bodies; default the field
    name), ``aliases`` (more spellings; the field name is always accepted), ``unit``, one-line
    ``help``, bounds (``min``/``max``, ``odd``, ``multiple_of``), ``choices`` (with ``case``
    "upper"/"lower" applied to a text value first), ``target`` (the spec's part after the colon),
    ``nested`` (a config dataclass whose options are spelled flat in its parent's), ``joined``
    ((key, part): spelled with a sibling as ``key=AxB``), ``extras`` (further keys, name -> type,
    collected into this field as sorted (name, value) pairs) and ``default_text`` (the default in
    words when it depends on other options). ``choices`` may be a function returning them, read
    at each check (a registry that grows). ``example`` is a valid value other than the default, for
    free text that no bound describes (a scene's object, a board's squares): docs and tests use it."""

    help: str = ""
    unit: str = ""
    key: str = ""
    aliases: tuple[str, ...] = ()
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    max_open: bool = False
    odd: bool = False
    multiple_of: int | None = None
    choices: tuple[str, ...] | Callable[[], tuple[str, ...]] | None = None
    case: str = ""
    target: bool = False
    nested: bool = False
    joined: tuple[str, int] | None = None
    extras: Callable[[], Mapping[str, Any]] | None = None
    default_text: str = ""
    example: Any = None


def option(default: Any = dataclasses.MISSING, *, factory: Callable[[], Any] | None = None, **opt: Any) -> Any:
    """A dataclass field with ``default`` (or ``factory``) described by ``Opt(**opt)``."""
    meta = {"option": Opt(**opt)}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def choices_of(o: Opt) -> tuple[str, ...] | None:
    """The allowed values of an option, or None when any value of its type is."""
    return o.choices() if callable(o.choices) else o.choices


def opt_of(f: dataclasses.Field) -> Opt | None:
    """The :class:`Opt` of a dataclass field, or None when it has none."""
    return f.metadata.get("option")


def key_of(f: dataclasses.Field) -> str:
    """The spelling of field ``f`` in specs, TOML and API bodies."""
    o = opt_of(f)
    return (o.key if o and o.key else "") or f.name


@functools.cache
def hints(cls: type) -> dict[str, Any]:
    """The resolved annotations of dataclass ``cls`` (the classes, not their strings); resolved once
    per class (each resolution compiles every annotation: 0.2 ms per MeasureOptions, 7 fields).
    Read-only: the dict is shared."""
    return typing.get_type_hints(cls)


@functools.lru_cache(maxsize=512)
def base_type(hint: Any) -> tuple[Any, bool]:
    """(the type without ``| None``, whether None is allowed)."""
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in args:
        rest = [a for a in args if a is not type(None)]
        return (rest[0] if len(rest) == 1 else hint), True
    return hint, False


@functools.lru_cache(maxsize=512)
def type_name(hint: Any) -> str:
    """A type in words for the API and the manual: bool, int, float, str, path, list, pairs, or a
    config class name (nested)."""
    t, _ = base_type(hint)
    if typing.get_origin(t) is typing.Literal:
        return "str"
    if typing.get_origin(t) is tuple:
        inner = typing.get_args(t)
        return "pairs" if inner and typing.get_origin(inner[0]) is tuple else "list"
    if t is Path:
        return "path"
    return getattr(t, "__name__", str(t))


def _is_whole(v: object) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _num(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else f"{v:g}"


def requirement(hint: Any, o: Opt) -> str:
    """What a value must be, in words: ``"an odd whole number from 1 to 51 (px)"``."""
    t, _ = base_type(hint)
    name = type_name(hint)
    if choices_of(o) is not None:
        return "one of " + ", ".join(choices_of(o))  # type: ignore[arg-type]
    if name == "bool":
        return "a boolean, true or false (1/0, yes/no or on/off in a spec)"
    word = {"int": "whole number", "float": "finite number"}.get(name, f"a {name}")
    if name in ("int", "float") and o.min == 0 and o.min_open and o.max is None and not (o.odd or o.multiple_of):
        return f"a positive {'whole ' if name == 'int' else ''}number" + (f" ({o.unit})" if o.unit else "")
    if name in ("int", "float"):
        word = ("an odd " if o.odd else "a ") + word
        if o.multiple_of:
            word += f", a multiple of {o.multiple_of},"
        lo, hi = o.min, o.max
        if lo is not None and hi is not None:
            word += (f" in {'(' if o.min_open else '['}{_num(lo)}, {_num(hi)}{')' if o.max_open else ']'}"
                     if o.min_open or o.max_open else f" from {_num(lo)} to {_num(hi)}")
        elif lo is not None:
            word += f" {'above' if o.min_open else 'of at least'} {_num(lo)}"
        elif hi is not None:
            word += f" {'below' if o.max_open else 'of at most'} {_num(hi)}"
        if o.unit:
            word += f" ({o.unit})"
    return word


def problem(value: object, hint: Any, o: Opt) -> str:
    """Why ``value`` does not fit the field (type ``hint``, metadata ``o``), or "" when it fits."""
    t, nullable = base_type(hint)
    if value is None:
        return "" if nullable else "missing"
    if o.nested or o.extras is not None:
        return ""
    name = type_name(hint)
    allowed = choices_of(o)
    if allowed is not None:
        return "" if isinstance(value, str) and value in allowed else "unknown"
    if name == "bool":
        return "" if isinstance(value, (bool, np.bool_)) else "not true/false"
    if name == "int" and not _is_whole(value):
        return "not a whole number"
    if name == "float" and not (_is_number(value) and math.isfinite(value)):
        return "not a finite number"
    if name in ("int", "float"):
        v = float(value)  # type: ignore[arg-type]
        if o.min is not None and (v < o.min or (o.min_open and v == o.min)):
            return "too small"
        if o.max is not None and (v > o.max or (o.max_open and v == o.max)):
            return "too large"
        if o.odd and int(value) % 2 == 0:  # type: ignore[call-overload]
            return "even"
        if o.multiple_of and int(value) % o.multiple_of:  # type: ignore[call-overload]
            return f"not a multiple of {o.multiple_of}"
        return ""
    if name in ("str", "path"):
        return "" if isinstance(value, (str, Path)) else "not text"
    return ""


def check(obj: object, error: type[Exception], prefix: str = "") -> None:
    """Raise ``error`` for the first field of dataclass instance ``obj`` whose value does not fit its
    :class:`Opt`: ``"{prefix}window=4 must be an odd whole number from 1 to 51 (px)"``."""
    hs = hints(type(obj))
    for f in dataclasses.fields(obj):  # type: ignore[arg-type]
        o = opt_of(f)
        if o is None:
            continue
        value = getattr(obj, f.name)
        if problem(value, hs[f.name], o):
            raise error(f"{prefix}{key_of(f)}={value!r} must be {requirement(hs[f.name], o)}")


def jsonable(value: Any) -> Any:
    """A default as JSON: paths and text as str, tuples as lists, a nested dataclass as its fields."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (tuple, list)):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def default_of(f: dataclasses.Field) -> Any:
    """The field's default value (its factory called), or ``dataclasses.MISSING``."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


@dataclasses.dataclass(frozen=True)
class OptionField:
    """One described field of a config dataclass: ``name``, ``key`` (its spelling), resolved type
    ``hint``, metadata ``opt`` and ``default`` (``dataclasses.MISSING`` when required)."""

    name: str
    key: str
    hint: Any
    opt: Opt
    default: Any

    @property
    def kind(self) -> str:
        """The type in words (:func:`type_name`)."""
        return type_name(self.hint)

    @property
    def base(self) -> Any:
        """The type without ``| None``."""
        return base_type(self.hint)[0]

    @property
    def nullable(self) -> bool:
        return base_type(self.hint)[1]

    @property
    def required(self) -> bool:
        return self.default is dataclasses.MISSING

    def choices(self) -> tuple[str, ...] | None:
        return choices_of(self.opt)

    def requirement(self) -> str:
        """What a value must be, in words (:func:`requirement`)."""
        return requirement(self.hint, self.opt)

    def help_text(self) -> str:
        """The one-line help, with ``|`` escaped for a Markdown table."""
        return self.opt.help.replace("|", "\\|")

    def problem(self, value: object) -> str:
        """Why ``value`` does not fit (:func:`problem`), "" when it does."""
        return problem(value, self.hint, self.opt)

    def example(self) -> Any:
        """A valid value other than the default: ``opt.example``, else one made from the bounds and
        choices (None when only ``opt.example`` could say one: free text)."""
        if self.opt.example is not None:
            return self.opt.example
        allowed = self.choices()
        if allowed is not None:
            return next((c for c in allowed if c != self.default), None)
        if self.kind == "bool":
            return not self.default if isinstance(self.default, bool) else True
        if self.kind not in ("int", "float"):
            return None
        o, base = self.opt, self.default if isinstance(self.default, (int, float)) else (self.opt.min or 0)
        step = o.multiple_of or (2 if o.odd else 1)
        lo, hi = o.min, o.max
        tries = [base + step, base - step, base * 2, (lo + hi) / 2 if lo is not None and hi is not None else base + 0.25,
                 (lo or 0) + step] if self.kind == "int" else [base * 1.5, base + 0.25, base * 0.5,
                                                             (lo + hi) / 2 if lo is not None and hi is not None else 1.0]
        for value in tries:
            value = int(value) if self.kind == "int" else float(value)
            if value != self.default and not self.problem(value):
                return value
        return None


def options_of(cls: type) -> tuple[OptionField, ...]:
    """The fields of dataclass ``cls`` declared with :func:`option`, in order."""
    hs = hints(cls)
    return tuple(OptionField(f.name, key_of(f), hs[f.name], o, default_of(f))
                 for f in dataclasses.fields(cls) if (o := opt_of(f)) is not None)


def describe(cls: type) -> list[dict[str, Any]]:
    """One JSON-ready entry per described field of ``cls`` (nested config classes flattened in place):
    name, key, aliases, type, default (None when required), default_text, min, max, min_open,
    max_open, odd, multiple_of, choices, unit, help, target, joined."""
    out: list[dict[str, Any]] = []
    hs = hints(cls)
    for f in dataclasses.fields(cls):
        o = opt_of(f)
        if o is None:
            continue
        if o.nested:
            out.extend(describe(base_type(hs[f.name])[0]))
            continue
        default = default_of(f)
        out.append({
            "name": f.name, "key": key_of(f), "aliases": list(o.aliases), "type": type_name(hs[f.name]),
            "default": None if default is dataclasses.MISSING else jsonable(default),
            "required": default is dataclasses.MISSING, "default_text": o.default_text,
            "min": o.min, "max": o.max, "min_open": o.min_open, "max_open": o.max_open, "odd": o.odd,
            "multiple_of": o.multiple_of, "choices": None if choices_of(o) is None else list(choices_of(o)),  # type: ignore[arg-type]
            "unit": o.unit, "help": o.help, "target": o.target, "joined": list(o.joined) if o.joined else None,
            "example": jsonable(o.example),
        })  # fmt: skip
    return out
