"""One parser for every option set: spec strings, TOML tables and API bodies into config dataclasses.

Each config dataclass (a source kind's, ``measure.MeasureOptions``) describes its options once, in
field metadata (:mod:`measure.fields`): spelling and aliases, type, bounds, unit, help. From that:

1. :func:`build` turns a mapping of spellings to values into the dataclass. Text values (a spec's
   ``?a=1&b=2``) are parsed by the field's type (yes/no flags, numbers, comma lists, ``WxH`` for a
   joined pair); typed values (TOML, JSON) must already have the type. Nested config dataclasses
   (a stereo pair's SGBM settings, its calibration file) are spelled flat. An unknown key raises
   the caller's typed error naming every known key; bounds are checked by the dataclass itself.
2. :func:`values_of` is the way back: the canonical spelling of every option that differs from
   the default, as text (a spec) or typed (a TOML table, an API body), so that parsing it gives
   an equal config (tests/device/test_configs.py round-trips every kind).
3. :func:`from_spec`, :func:`from_table`, :func:`to_spec` and :func:`to_table` add a source
   kind's target (the spec's part after the colon, ``Backend.target`` in a table).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from measure import Opt, OptionField, options_of

from device.base import BACKENDS, SourceSpec, backend, parse_flag
from device.errors import SourceError

T = TypeVar("T")


@dataclass(frozen=True)
class Slot:
    """Where a spelling goes: ``path`` (field names from the top dataclass down), the field's type
    ``hint`` and :class:`Opt`; a joined key lists its parts' paths in ``parts`` instead."""

    path: tuple[str, ...]
    hint: Any
    opt: Opt
    parts: tuple[tuple[tuple[str, ...], Any, Opt], ...] = ()


def slots(cls: type, prefix: tuple[str, ...] = ()) -> dict[str, Slot]:
    """Every spelling dataclass ``cls`` accepts (canonical keys, field names, aliases, joined keys)."""
    out: dict[str, Slot] = {}
    joined: dict[str, list[tuple[int, tuple[str, ...], Any, Opt]]] = {}
    for f in options_of(cls):
        o = f.opt
        if o.extras is not None or o.target:
            continue
        path = (*prefix, f.name)
        if o.nested:
            out.update(slots(f.base, path))
        elif o.joined:
            joined.setdefault(o.joined[0], []).append((o.joined[1], path, f.hint, o))
        else:
            for spelling in dict.fromkeys((f.key, f.name, *o.aliases)):
                out[spelling] = Slot(path, f.hint, o)
    for key, parts in joined.items():
        parts.sort(key=lambda p: p[0])
        out[key] = Slot(prefix, str, Opt(), tuple((p, h, o) for _, p, h, o in parts))
    return out


def extras(cls: type, prefix: tuple[str, ...] = ()) -> dict[str, tuple[tuple[str, ...], Any]]:
    """Keys collected into an ``extras`` field: key -> (that field's path, the value's type)."""
    out: dict[str, tuple[tuple[str, ...], Any]] = {}
    for f in options_of(cls):
        if f.opt.nested:
            out.update(extras(f.base, (*prefix, f.name)))
        elif f.opt.extras is not None:
            out.update({k: ((*prefix, f.name), t) for k, t in f.opt.extras().items()})
    return out


def known_keys(cls: type) -> list[str]:
    """The canonical spellings of ``cls``'s options, in field order (what an unknown key's error lists)."""
    out: list[str] = []
    for f in options_of(cls):
        if f.opt.target:
            continue
        if f.opt.nested:
            out += known_keys(f.base)
        elif f.opt.extras is not None:
            out += list(f.opt.extras())
        else:
            out.append(f.opt.joined[0] if f.opt.joined else f.key)
    return list(dict.fromkeys(out))


def _field(cls: type, path: tuple[str, ...]) -> OptionField:
    for name in path[:-1]:
        cls = {f.name: f for f in options_of(cls)}[name].base
    return {f.name: f for f in options_of(cls)}[path[-1]]


def target_field(cls: type) -> OptionField | None:
    """The field a spec's target (after the colon) fills, or None."""
    return next((f for f in options_of(cls) if f.opt.target), None)


def convert(value: object, hint: Any, o: Opt, key: str, error: type[Exception], kind: str) -> Any:
    """``value`` as the field's type: text parsed (a spec), typed values checked (TOML, JSON)."""
    f = OptionField(key, key, hint, o, None)
    name, nullable = f.kind, f.nullable
    what = f"{kind} option {key}={value!r} must be {f.requirement()}"
    try:
        if isinstance(value, str):
            text = value.strip()
            if nullable and not text:
                return None
            if name == "bool":
                return parse_flag(text) if text else False
            if name == "int":
                number = float(text)
                if not number.is_integer():
                    raise ValueError(text)
                return int(number)
            if name == "float":
                return float(text)
            if name == "path":
                return Path(text)
            if name == "list":
                return tuple(p.strip() for p in text.split(",") if p.strip())
            return text.upper() if o.case == "upper" else text.lower() if o.case == "lower" else text
        if name == "bool" and isinstance(value, bool):
            return value
        if name == "path" and isinstance(value, Path):
            return value
        if name == "int" and not isinstance(value, bool) and isinstance(value, (int, float)):
            if float(value).is_integer():
                return int(value)
        if name == "float" and not isinstance(value, bool) and isinstance(value, (int, float)):
            return float(value)
        if name == "list" and isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return tuple(value)
        if value is None and nullable:
            return None
    except ValueError:
        pass
    raise error(what)


def build(cls: type[T], values: Mapping[str, object], *, target: object = None, kind: str = "",
          error: type[Exception] = SourceError) -> T:
    """Dataclass ``cls`` from spellings and values (text or typed); ``target`` fills the target
    field. ``error`` is raised for an unknown key, a value of the wrong type, and by the dataclass
    for a value out of bounds (another ValueError of a nested dataclass is raised as ``error``)."""
    sl, ex = slots(cls), extras(cls)
    tree: dict[tuple[str, ...], Any] = {}
    collected: dict[tuple[str, ...], dict[str, Any]] = {}
    label = kind or cls.__name__
    for key, value in values.items():
        if isinstance(value, Mapping):
            raise error(f"{label} option {key} is a table; write the options of a kind flat in its own table "
                        f"(e.g. ndisp = 64 under [source], not under [source.{key}])")
        if key in sl:
            slot = sl[key]
            if slot.parts:
                pieces = value.lower().split("x") if isinstance(value, str) else value
                if not isinstance(pieces, (list, tuple)) or len(pieces) != len(slot.parts):
                    raise error(f"{label} option {key}={value!r} must be {'x'.join(p[0][-1].upper() for p in slot.parts)}, e.g. 1280x720")
                for (path, hint, o), piece in zip(slot.parts, pieces):
                    tree[path] = convert(piece, hint, o, key, error, label)
                continue
            if slot.path in tree:
                raise error(f"{label} option {key} is given twice (under two spellings); keep one")
            tree[slot.path] = convert(value, slot.hint, slot.opt, key, error, label)
        elif key in ex:
            path, t = ex[key]
            collected.setdefault(path, {})[key] = convert(value, t, Opt(), key, error, label)
        else:
            raise error(f"unknown {label} option {key!r}; use any of: {', '.join(known_keys(cls))}")
    for path, found in collected.items():
        tree[path] = tuple(sorted(found.items()))
    tf = target_field(cls)
    if tf is not None and target not in (None, "", [], ()):
        tree[(tf.name,)] = convert(target, tf.hint, tf.opt, tf.key, error, label)
    return _make(cls, tree, (), error, label)


def _make(cls: type[T], tree: Mapping[tuple[str, ...], Any], prefix: tuple[str, ...], error: type[Exception], label: str) -> T:
    kwargs: dict[str, Any] = {}
    for f in options_of(cls):
        path = (*prefix, f.name)
        if f.opt.nested:
            if any(p[: len(path)] == path for p in tree):
                kwargs[f.name] = _make(f.base, tree, path, error, label)
        elif path in tree:
            kwargs[f.name] = tree[path]
    try:
        return cls(**kwargs)
    except TypeError as exc:  # a required field left out
        raise error(f"{label}: {exc}") from None
    except ValueError as exc:
        if isinstance(exc, error):
            raise
        raise error(f"{label} options: {exc}") from None


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, (tuple, list)):
        return ",".join(_text(v) for v in value)
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
    return str(value)


def _typed(value: Any) -> Any:
    if isinstance(value, (tuple, list)):
        return [_typed(v) for v in value]
    return str(value) if isinstance(value, Path) else value


def values_of(config: object, *, text: bool, base: object = None) -> dict[str, Any]:
    """Canonical spelling -> value of each option of ``config`` that differs from ``base`` (default:
    the dataclass with only its target set), as text (``text=True``: a spec's query) or typed."""
    cls = type(config)
    if base is None:
        tf = target_field(cls)
        base = build(cls, {}, target=None if tf is None else getattr(config, tf.name), error=SourceError)
    out: dict[str, Any] = {}
    enc = _text if text else _typed
    for key, slot in slots(cls).items():
        if slot.parts:
            now = [_get(config, p) for p, _, _ in slot.parts]
            if now != [_get(base, p) for p, _, _ in slot.parts]:
                out[key] = "x".join(_text(v) for v in now)
        elif key == _field(cls, slot.path).key:
            value = _get(config, slot.path)
            if value != _get(base, slot.path) and value is not None:
                out[key] = enc(value)
    for key, (path, _) in extras(cls).items():
        pairs = dict(_get(config, path))
        if key in pairs and pairs.get(key) != dict(_get(base, path)).get(key):
            out[key] = enc(pairs[key])
    return out


def _get(obj: object, path: tuple[str, ...]) -> Any:
    for name in path:
        obj = getattr(obj, name)
    return obj


def config_class(kind: str) -> type:
    """The config dataclass of source kind ``kind`` (its module imported now)."""
    entry = backend(kind)
    return getattr(importlib.import_module(entry.module), entry.config)


def from_spec(cls: type[T], spec: SourceSpec, missing: Exception | None = None) -> T:
    """``cls`` from a parsed spec string; ``missing`` is raised when the spec names no target and
    ``cls``'s target field has no default."""
    tf = target_field(cls)
    if missing is not None and not spec.target and tf is not None and tf.required:
        raise missing
    return build(cls, spec.params, target=spec.target, kind=spec.kind)


def from_table(table: Mapping[str, object]) -> object:
    """The config a TOML ``[source]`` table or an API body means: ``kind`` picks the kind, the kind's
    target key (``Backend.target``) the target, every other key an option (typed, or text as in a spec)."""
    kind = table.get("kind")
    if not isinstance(kind, str) or not kind:
        raise SourceError(f"the source table needs kind = one of {', '.join(repr(k) for k in BACKENDS)}")
    kind = kind.lower()
    entry = backend(kind)
    target = table.get(entry.target, "")
    if isinstance(target, bool) or not isinstance(target, (str, list, int, float)):
        raise SourceError(f"{kind} {entry.target} = {target!r} must be text, a number or a list of text")
    module = importlib.import_module(entry.module)
    if not target:
        module.config_from_spec(SourceSpec(kind))  # the kind's own error when its target is required
    rest = {k: v for k, v in table.items() if k not in ("kind", entry.target)}
    return build(getattr(module, entry.config), rest, target=target, kind=kind)


def spec_from_table(table: Mapping[str, object]) -> SourceSpec:
    """The spec a TOML ``[source]`` table (or an API body) means, after its kind's config accepted it:
    ``{kind = "sim", scene = "boxes", distance = 6}`` is ``sim:boxes?distance=6``."""
    config = from_table(table)
    return to_spec(str(table["kind"]).lower(), config)


def _target_text(config: object) -> tuple[str, Any]:
    tf = target_field(type(config))
    if tf is None:
        return "", None
    value = getattr(config, tf.name)
    return _text(value) if value not in (None, "") else "", value


def to_spec(kind: str, config: object) -> SourceSpec:
    """The spec of ``config``: its target and the options that differ from the defaults."""
    return SourceSpec(kind, _target_text(config)[0], values_of(config, text=True))


def to_table(kind: str, config: object) -> dict[str, Any]:
    """The TOML ``[source]`` table (or API body) of ``config``: kind, target key, options that differ."""
    table: dict[str, Any] = {"kind": kind}
    text, value = _target_text(config)
    if text:
        table[backend(kind).target] = _typed(value) if isinstance(value, (tuple, list)) else text
    return {**table, **values_of(config, text=False)}


def _cell(value: Any) -> str:
    if value is None or value == "":
        return "—"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return ", ".join(_cell(v) for v in value) or "—"
    return f"`{_text(value)}`"


def _bounds(f: OptionField) -> str:
    o, allowed = f.opt, f.choices()
    if allowed is not None:
        return ", ".join(f"`{c}`" for c in allowed)
    if f.kind == "bool":
        return "true, false"
    parts = []
    if o.min is not None or o.max is not None:
        lo = "" if o.min is None else ("> " if o.min_open else "≥ ") + _text(o.min)
        hi = "" if o.max is None else ("< " if o.max_open else "≤ ") + _text(o.max)
        parts.append(" and ".join(p for p in (lo, hi) if p))
    if o.odd:
        parts.append("odd")
    if o.multiple_of:
        parts.append(f"multiple of {o.multiple_of}")
    return ", ".join(parts) or "—"


def markdown(cls: type, target_key: str = "") -> str:
    """The option table of dataclass ``cls`` in Markdown (docs/usage.md holds one per option set,
    checked against this by tests/device/test_configs.py): spelling, type, default, allowed, unit, what."""
    rows = ["| option | type | default | allowed | unit | what |", "| --- | --- | --- | --- | --- | --- |"]

    def add(c: type) -> None:
        joined: dict[str, list[OptionField]] = {}
        for f in options_of(c):
            o = f.opt
            if o.nested:
                add(f.base)
                continue
            if o.joined:
                joined.setdefault(o.joined[0], []).append(f)
                if len(joined[o.joined[0]]) == 2:
                    w, h = sorted(joined[o.joined[0]], key=lambda g: g.opt.joined[1])  # type: ignore[index]
                    default = w.opt.default_text or f"`{w.default}x{h.default}`"
                    rows.append(f"| `{o.joined[0]}` | WxH | {default} | {_bounds(w)} each | {o.unit} "
                                f"| {w.help_text()}, {h.help_text()} |")
                continue
            key = f"any of {', '.join(f'`{k}`' for k in o.extras())}" if o.extras is not None and len(o.extras()) < 6 \
                else "any SensorModel field" if o.extras is not None else f"`{(target_key if o.target else '') or f.key}`"
            if o.target:
                key += " (target)"
            default = o.default_text or ("required" if f.required else _cell(f.default))
            kind = "by name" if o.extras is not None else f.kind
            rows.append(f"| {key} | {kind} | {default} | {_bounds(f)} | {o.unit} | {f.help_text()} |")

    add(cls)
    return "\n".join(rows) + "\n"


def option_tables() -> dict[str, str]:
    """Name -> Markdown table of every option set: ``measure`` and each source kind."""
    from measure import MeasureOptions

    out = {"measure": markdown(MeasureOptions)}
    for kind in sorted(BACKENDS):
        out[kind] = markdown(config_class(kind), BACKENDS[kind].target)
    return out


def fill_tables(page: str) -> str:
    """``page`` with every block between ``<!-- options:NAME -->`` and ``<!-- /options:NAME -->``
    replaced by :func:`option_tables`'s table NAME (docs/usage.md is written with it)."""
    tables = option_tables()
    for name, table in tables.items():
        start, end = f"<!-- options:{name} -->\n", f"<!-- /options:{name} -->"
        a = page.find(start)
        b = page.find(end, a)
        if a >= 0 and b >= 0:
            page = page[: a + len(start)] + table + page[b:]
    return page

