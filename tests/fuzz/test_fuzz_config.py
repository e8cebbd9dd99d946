"""Fuzzing TOML service configs: generated documents and byte-mutated shipped files.

Every file either loads or raises ConfigError naming the file; never another exception or a
warning. A config that loads is one the service can start from: its source spec parses back to
the same values and the backend accepts it (not opened: no device here).
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

from hypothesis import event, given
from hypothesis import strategies as st

from device import BACKENDS, SourceError, SourceSpec, make_source
from fuzzing import EDGE_FLOATS, ODD_TEXT, typed_or_answer
from service.config import ConfigError, ServerConfig, load_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SHIPPED = sorted(CONFIGS.glob("*.toml"))
# kind -> {key: a sensible value}: the [source] tables of the shipped files, and a path for the file kinds
SOURCE_KEYS: dict[str, dict[str, object]] = {kind: {BACKENDS[kind].target: "rec/desk"} for kind in BACKENDS}
for _file in SHIPPED:
    _table = tomllib.loads(_file.read_text(encoding="utf-8")).get("source", {})
    SOURCE_KEYS[_table["kind"]].update({k: v for k, v in _table.items() if k != "kind"})


def toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(k, ensure_ascii=False)} = {toml_value(v)}" for k, v in value.items()) + "}"
    return json.dumps(str(value), ensure_ascii=False).replace("\x7f", "\\u007f")


SCALARS = st.one_of(
    st.booleans(), st.integers(-(2**63), 2**63 - 1), st.integers(-10, 5000), EDGE_FLOATS.filter(lambda v: v == v or True),
    ODD_TEXT, st.sampled_from(["sim", "oak", "v4l2", "replay", "poster", "indoor", "model", "stereo", "MJPG",
                               "side-by-side", "default", "127.0.0.1", "0.0.0.0", "rec/desk", "x.db"]),
)
VALUES = st.one_of(SCALARS, st.lists(SCALARS, max_size=3), st.dictionaries(st.sampled_from(["a", "mode", "wls"]), SCALARS, max_size=2))


def _field_value(default: object) -> st.SearchStrategy:
    """A value of the default's own type near it, or anything."""
    if isinstance(default, bool):
        near = st.booleans()
    elif isinstance(default, int):
        near = st.one_of(st.just(default), st.integers(-1, 5000), st.sampled_from([0, 1, 16, 64, 640, 65536]))
    elif isinstance(default, float):
        near = st.one_of(st.just(default), st.floats(-1.0, 200.0), st.sampled_from([0.0, 0.5, 0.8, 1.0, 20.0, 30.0]))
    elif isinstance(default, str):
        near = st.one_of(st.just(default), ODD_TEXT)
    else:
        near = VALUES
    return st.one_of(near, near, near, near, near, VALUES)


@st.composite
def documents(draw: st.DrawFn) -> str:
    lines: list[str] = []
    if draw(st.booleans()):
        lines.append("[server]")
        for name in draw(st.lists(st.sampled_from(sorted(ServerConfig.model_fields)), max_size=4, unique=True)):
            lines.append(f"{name} = {toml_value(draw(_field_value(ServerConfig.model_fields[name].default)))}")
    if draw(st.integers(0, 4)):
        kind = draw(st.sampled_from(sorted(BACKENDS))) if draw(st.integers(0, 5)) else draw(ODD_TEXT)
        known = SOURCE_KEYS.get(kind, SOURCE_KEYS["sim"])
        lines.append("[source]")
        if draw(st.integers(0, 9)):
            lines.append(f"kind = {toml_value(kind)}")
        for name in draw(st.lists(st.sampled_from(sorted(known)), max_size=5, unique=True)):
            lines.append(f"{name} = {toml_value(draw(_field_value(known[name])))}")
        if draw(st.integers(0, 5)) == 0:  # a nested table: refused, the options of a kind are flat
            lines.append("[source.sgbm]")
            lines.append(f"ndisp = {toml_value(draw(st.one_of(st.integers(-16, 1100), VALUES)))}")
    if draw(st.integers(0, 9)) == 0:
        key = draw(ODD_TEXT)
        key = toml_value(key) if draw(st.integers(0, 2)) else key  # bare: mostly not TOML
        lines.insert(draw(st.integers(0, len(lines))), f"{key} = {toml_value(draw(VALUES))}")
    return "\n".join(lines) + "\n"


@st.composite
def mutated_files(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(SHIPPED)).read_bytes())
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["flip", "insert", "delete", "truncate"]))
        i = draw(st.integers(0, max(0, len(data) - 1)))
        if op == "flip" and data:
            data[i] = draw(st.integers(0, 255))
        elif op == "insert":
            data[i:i] = draw(st.sampled_from([b"\xff", b"\x00", b"=", b"[", b"]", b'"', b"\n", b"1e999", b"\xc3", "é".encode()]))
        elif op == "delete" and data:
            del data[i : i + draw(st.integers(1, 8))]
        elif op == "truncate":
            del data[i:]
    return bytes(data)


def _check(path: Path) -> None:
    cfg = typed_or_answer(lambda: load_config(path), ConfigError)
    if cfg is None:
        try:
            load_config(path)
        except ConfigError as exc:
            assert str(path) in str(exc), f"the message does not name the file: {exc}"
            event(f"rejected: {str(exc)[len(str(path)) + 2:][:40]}")
        return
    if cfg.source is None:
        event("loaded, no source")
        return
    parsed = typed_or_answer(lambda: SourceSpec.parse(cfg.source), SourceError)
    assert parsed is not None, f"the config loads but its spec {cfg.source!r} does not parse"
    event(f"loaded, source {parsed.kind}")
    table = tomllib.loads(path.read_text(encoding="utf-8"))["source"]
    assert parsed.kind == table["kind"].lower()
    if BACKENDS[parsed.kind].target == "path" and isinstance(table.get("path"), str):
        assert parsed.target == table["path"], (cfg.source, table["path"])
    src = typed_or_answer(lambda: make_source(parsed), SourceError)
    assert src is not None, f"the config loads but the {parsed.kind} backend rejects its spec {cfg.source!r}"


@given(documents())
def test_generated_configs_load_or_name_the_file(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    path.write_text(text, encoding="utf-8")
    _check(path)


@given(mutated_files())
def test_mutated_shipped_configs_load_or_name_the_file(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("cfg") / "mutated.toml"
    path.write_bytes(data)
    _check(path)
