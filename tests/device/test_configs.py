"""One description per option set: from each config dataclass's field metadata alone, every option
of every source kind and of the measure options is written as a spec string, a TOML table and an
API body, parsed back and compared; a bound violation and an unknown key are typed errors in all three."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from urllib.parse import parse_qsl

import pytest

from device import BACKENDS, SourceError, SourceSpec, source_config
from device import configs
from measure import MeasureError, MeasureOptions, options_of

KINDS = sorted(BACKENDS)
# Fields a config keeps for code, not for users: no spelling in specs, tables or bodies.
INTERNAL = {("SGBMConfig", "disp12_max_diff"), ("SGBMConfig", "min_disparity"), ("SGBMConfig", "pre_filter_cap")}


def toml_text(table: dict) -> str:
    """A flat TOML table as text (strings, numbers, booleans, lists of them)."""

    def value(v: object) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return json.dumps(v)  # a TOML basic string

    return "[source]\n" + "".join(f"{k} = {value(v)}\n" for k, v in table.items())


def flat_options(cls: type, prefix: tuple = ()) -> list:
    """(path, OptionField) of every described field, nested config classes flattened."""
    out = []
    for f in options_of(cls):
        if f.opt.nested:
            out += flat_options(f.base, (*prefix, f.name))
        else:
            out.append(((*prefix, f.name), f))
    return out


def base_target(cls: type) -> object:
    tf = configs.target_field(cls)
    return None if tf is None else (tf.example() if tf.required else tf.default)


def examples(kind: str) -> list[tuple[str, str, object]]:
    """(kind, spelling, example value) of every option of the kind, made from the metadata."""
    cls = configs.config_class(kind)
    out = []
    for _, f in flat_options(cls):
        if f.opt.target:
            continue
        if f.opt.extras is not None:
            key, value = f.example()[0]
            out.append((kind, key, value))
        elif f.opt.joined:
            continue  # below, with its sibling
        else:
            out.append((kind, f.key, f.example()))
    joined: dict[str, list] = {}
    for _, f in flat_options(cls):
        if f.opt.joined:
            joined.setdefault(f.opt.joined[0], []).append((f.opt.joined[1], f.example()))
    out += [(kind, key, [v for _, v in sorted(parts)]) for key, parts in joined.items()]
    return out


CASES = [case for kind in KINDS for case in examples(kind)]


def test_every_field_of_every_config_is_described():
    missing = []
    for kind in KINDS:
        cls = configs.config_class(kind)
        todo = [cls]
        while todo:
            c = todo.pop()
            described = {f.name: f for f in options_of(c)}
            for name in c.__dataclass_fields__:
                if name not in described and (c.__name__, name) not in INTERNAL:
                    missing.append(f"{kind}: {c.__name__}.{name}")
            todo += [f.base for f in described.values() if f.opt.nested]
            missing += [f"{kind}: {c.__name__}.{f.name} has no help" for f in described.values() if not f.opt.help]
    assert not missing, missing


@pytest.mark.parametrize("kind", KINDS)
def test_the_table_key_of_the_target_is_the_target_field(kind):
    tf = configs.target_field(configs.config_class(kind))
    assert tf is not None and tf.key == BACKENDS[kind].target


@pytest.mark.parametrize("kind,key,value", CASES, ids=[f"{k}-{key}" for k, key, _ in CASES])
def test_each_option_round_trips_through_spec_toml_and_api(kind, key, value):
    cls = configs.config_class(kind)
    assert value is not None, f"{kind} option {key} has no example: give its metadata one"
    config = configs.build(cls, {key: value}, target=base_target(cls), kind=kind)
    spec = str(configs.to_spec(kind, config))
    assert source_config(spec) == config
    assert source_config(SourceSpec.parse(spec)) == config
    table = configs.to_table(kind, config)
    assert source_config(tomllib.loads(toml_text(table))["source"]) == config
    assert source_config(json.loads(json.dumps(table))) == config
    # the service's path: the table becomes a spec string, parsed again when the source starts
    from service.config import parse_config

    served = parse_config(tomllib.loads(toml_text(table)), "test.toml").source
    assert source_config(served) == config


def bad_values(f) -> list:
    """Values just outside the option's bounds or choices, and one of a wrong type."""
    o, out = f.opt, []
    if f.choices() is not None:
        out.append("no-such-choice")
    if f.kind in ("int", "float"):
        step = 1 if f.kind == "int" else 1e-6
        if o.min is not None:
            out.append(o.min if o.min_open else o.min - step)
        if o.max is not None:
            out.append(o.max if o.max_open else o.max + step)
        if o.odd:
            out.append(int(f.example()) + 1)
        out.append("not-a-number")
    if f.kind == "bool":
        out.append("maybe")
    return [int(v) if f.kind == "int" and isinstance(v, float) and v.is_integer() else v for v in out]


BAD = [(kind, f.key, v) for kind in KINDS for path, f in flat_options(configs.config_class(kind))
       if not f.opt.target and not f.opt.joined and f.opt.extras is None for v in bad_values(f)]


@pytest.mark.parametrize("kind,key,value", BAD, ids=[f"{k}-{key}={v}" for k, key, v in BAD])
def test_a_value_out_of_bounds_is_a_typed_error_in_all_three(kind, key, value):
    cls = configs.config_class(kind)
    target = configs._text(base_target(cls)) if base_target(cls) is not None else ""
    tf = configs.target_field(cls)
    spec = SourceSpec(kind, target if target != configs._text(tf.default) else "", {key: configs._text(value)})
    table = {"kind": kind, BACKENDS[kind].target: target, key: value} if target else {"kind": kind, key: value}
    for spelling in (str(spec), tomllib.loads(toml_text(table))["source"], json.loads(json.dumps(table))):
        with pytest.raises(SourceError, match=key):
            source_config(spelling)


@pytest.mark.parametrize("kind", KINDS)
def test_an_unknown_key_is_a_typed_error_naming_the_known_keys(kind):
    cls = configs.config_class(kind)
    known = configs.known_keys(cls)
    target = base_target(cls)
    text = configs._text(target) if target is not None else ""
    table = {"kind": kind, BACKENDS[kind].target: text, "no_such_key": 1}
    spellings = (f"{kind}:{text}?no_such_key=1", tomllib.loads(toml_text(table))["source"], json.loads(json.dumps(table)))
    for spelling in spellings:
        with pytest.raises(SourceError, match="no_such_key") as err:
            source_config(spelling)
        assert all(k in str(err.value) for k in known)


MEASURE = [(f.key, f.example()) for f in options_of(MeasureOptions)]


@pytest.mark.parametrize("key,value", MEASURE, ids=[k for k, _ in MEASURE])
def test_each_measure_option_round_trips_through_query_and_toml(key, value):
    options = configs.build(MeasureOptions, {key: value}, error=MeasureError)
    assert options != MeasureOptions() and getattr(options, key) == value
    query = "&".join(f"{k}={v}" for k, v in configs.values_of(options, text=True).items())
    assert configs.build(MeasureOptions, dict(parse_qsl(query)), error=MeasureError) == options
    table = configs.values_of(options, text=False)
    toml = "".join(f"{k} = {json.dumps(v)}\n" for k, v in table.items())
    assert configs.build(MeasureOptions, tomllib.loads(toml), error=MeasureError) == options


def test_measure_option_errors_are_typed():
    with pytest.raises(MeasureError, match="window=4 must be an odd"):
        configs.build(MeasureOptions, {"window": "4"}, error=MeasureError)
    with pytest.raises(MeasureError, match="window=53"):
        configs.build(MeasureOptions, {"window": 53}, error=MeasureError)
    with pytest.raises(MeasureError, match="click_px"):
        configs.build(MeasureOptions, {"click_px": math.nan}, error=MeasureError)
    with pytest.raises(MeasureError, match="unknown MeasureOptions option 'colour'; use any of: method, support_fraction"):
        configs.build(MeasureOptions, {"colour": "red"}, error=MeasureError)


REWRITE = ('.venv/bin/python -c "import pathlib, device.configs as c; p = pathlib.Path(\'docs/usage.md\'); '
           'p.write_text(c.fill_tables(p.read_text()))"')


def test_the_manual_s_option_tables_are_the_metadata():
    page = (Path(__file__).resolve().parents[2] / "docs" / "usage.md").read_text()
    for name in configs.option_tables():
        assert f"<!-- options:{name} -->" in page, f"docs/usage.md has no table for {name}"
    assert configs.fill_tables(page) == page, f"docs/usage.md's option tables differ from the metadata; run {REWRITE}"


def test_a_drifted_table_is_found():
    page = (Path(__file__).resolve().parents[2] / "docs" / "usage.md").read_text()
    assert configs.fill_tables(page.replace("| `window` | int | `5` |", "| `window` | int | `7` |")) == page
    assert page.replace("| `window` | int | `5` |", "| `window` | int | `7` |") != page
