"""The API validates measure options into MeasureOptions from the core's one description: every
option's example round-trips through a JSON body, every value out of the core's bounds is a 422
naming the option, and ``GET /api/options`` answers the methods, defaults and bounds themselves."""

from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from measure import MAX_FRAMES, METHODS, MeasureOptions, describe_options, options_of
from service.schemas import OptionsIn
from service_client import latest, make_client, measure

FIELDS = options_of(MeasureOptions)


@pytest.mark.parametrize("field", FIELDS, ids=[f.name for f in FIELDS])
def test_each_option_round_trips_through_an_api_body(field):
    body = json.loads(json.dumps({field.key: field.example()}))
    options = OptionsIn.model_validate(body).to_options()
    assert options == MeasureOptions(**{field.name: field.example()}) != MeasureOptions()
    assert OptionsIn.model_validate(OptionsIn(**body).model_dump()).to_options() == options


def out_of_bounds(field) -> list:
    o, out = field.opt, []
    step = 1 if field.kind == "int" else 1e-6
    if o.min is not None:
        out.append(o.min - step)
    if o.max is not None:
        out.append(o.max + step)
    if o.odd:
        out.append(field.default + 1)
    if field.choices() is not None:
        out.append("no-such-method")
    if field.kind == "bool":
        out.append("yes")
    return [int(v) if field.kind == "int" else v for v in out]


BAD = [(f, v) for f in FIELDS for v in out_of_bounds(f)]


@pytest.mark.parametrize("field,value", BAD, ids=[f"{f.name}={v}" for f, v in BAD])
def test_the_api_and_the_core_refuse_the_same_values(field, value):
    with pytest.raises(ValidationError, match=field.name):
        OptionsIn.model_validate({field.name: value})
    with pytest.raises(ValueError, match=field.name):
        MeasureOptions(**{field.name: value})


def test_options_endpoint_is_the_description_and_the_page_gets_it(tmp_path):
    with make_client(tmp_path) as c:
        r = c.get("/api/options")
        assert r.status_code == 200
        body = r.json()
        assert body == {"methods": list(METHODS), "fields": json.loads(json.dumps(describe_options(MeasureOptions))),
                        "frames": {"min": 1, "max": MAX_FRAMES}}
        window = next(f for f in body["fields"] if f["name"] == "window")
        assert (window["min"], window["max"], window["odd"], window["default"]) == (1, 51, True, 5)
        f = latest(c)
        bad = measure(c, f["id"], (10, 24), (54, 24), window=window["max"] + 2)
        assert bad.status_code == 422 and "window" in bad.text
        even = measure(c, f["id"], (10, 24), (54, 24), window=4)
        assert even.status_code == 422 and "odd" in even.text
        ok = measure(c, f["id"], (10, 24), (54, 24), window=window["max"], method=body["methods"][-1])
        assert ok.status_code == 200, ok.text
        assert ok.json()["options"]["window"] == window["max"] and ok.json()["method"] == body["methods"][-1]
