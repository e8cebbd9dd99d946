"""The API describes its answers: every route's 200 answer has a schema in /docs, the
schemas are the ones real answers validate against, and the options a request takes are the
measuring core's."""

from __future__ import annotations

import dataclasses

import pytest
from fastapi.testclient import TestClient
from pydantic import TypeAdapter

from measure import MeasureOptions
from service import schemas
from service.app import create_app
from service.schemas import OptionsIn

SIM = "sim:boxes?fps=20&width=320&height=180&distance=3"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(SIM, db_path=tmp_path_factory.mktemp("api") / "h.db", capture_fps=50.0, ring_size=4)
    with TestClient(app, base_url="http://127.0.0.1") as c:
        yield c


def _operations(spec: dict):
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            yield method.upper(), path, op


def test_every_route_documents_its_answer(client):
    spec = client.app.openapi()
    ops = list(_operations(spec))
    assert len(ops) >= 27  # every route of service/routers
    for method, path, op in ops:
        content = op["responses"].get("200", {}).get("content", {})
        assert content, f"{method} {path} documents no 200 answer"
        for media, body in content.items():
            schema = body.get("schema", {})
            assert schema and (schema.get("$ref") or schema.get("type")), f"{method} {path} {media}: empty schema"
        if path.endswith((".png", ".jpg")):
            assert set(content) <= {"image/png", "image/jpeg"}, (path, content)


def _model_of(spec: dict, method: str, path: str):
    """The response type /docs names for a route, as the class in service.schemas."""
    schema = spec["paths"][path][method.lower()]["responses"]["200"]["content"]["application/json"]["schema"]
    if schema.get("type") == "array":
        return list[getattr(schemas, schema["items"]["$ref"].rsplit("/", 1)[-1])]
    return getattr(schemas, schema["$ref"].rsplit("/", 1)[-1])


def test_real_answers_validate_against_the_documented_models(client):
    spec = client.app.openapi()
    checked: set[tuple[str, str]] = set()

    def call(method: str, path: str, url: str, **kw) -> dict:
        if method != "GET" and "json" not in kw:
            kw["headers"] = {"Content-Type": "application/json"}  # the guard asks it of every write
        r = client.request(method, url, **kw)
        assert r.status_code == 200, (url, r.text)
        TypeAdapter(_model_of(spec, method, path)).validate_python(r.json(), strict=False)
        checked.add((method, path))
        return r.json()

    frame = call("GET", "/api/frames/latest", "/api/frames/latest?wait=5")
    fid = frame["id"]
    assert frame["truth"] is not None and frame["width"] == 320  # the sim's truth goes through TruthOut
    call("GET", "/api/frames/{frame_id}", f"/api/frames/{fid}")
    call("POST", "/api/frames/{frame_id}/freeze", f"/api/frames/{fid}/freeze")
    call("GET", "/api/frames/{frame_id}/depth", f"/api/frames/{fid}/depth", params={"x": 160, "y": 90})
    call("GET", "/api/frames/{frame_id}/depth-scale", f"/api/frames/{fid}/depth-scale")
    p1, p2 = frame["truth"]["p1_px"], frame["truth"]["p2_px"]
    record = call("POST", "/api/measure", "/api/measure", json={"frame_id": fid, "p1": p1, "p2": p2})
    mid = record["id"]
    assert record["samples_px"] and record["quality"] and isinstance(record["weak_stretches"], list)
    mid_px = [(a + b) / 2 for a, b in zip(p1, p2)]
    shape = call("POST", "/api/shapes", "/api/shapes", json={"frame_id": fid, "kind": "path", "points": [p1, mid_px, p2]})
    assert shape["kind"] == "path" and len(shape["result"]["parts"]) == 2
    call("GET", "/api/measurements/{mid}", f"/api/measurements/{shape['id']}")
    call("GET", "/api/measurements", "/api/measurements")
    call("GET", "/api/measurements/{mid}", f"/api/measurements/{mid}")
    call("PATCH", "/api/measurements/{mid}", f"/api/measurements/{mid}", json={"name": "box", "note": "edge"})
    call("POST", "/api/measurements/{mid}/pin", f"/api/measurements/{mid}/pin")
    call("DELETE", "/api/measurements/{mid}/pin", f"/api/measurements/{mid}/pin")
    call("POST", "/api/measurements/{mid}/open", f"/api/measurements/{mid}/open")
    call("GET", "/api/measurements.json", "/api/measurements.json")
    call("DELETE", "/api/frames/{frame_id}/freeze", f"/api/frames/{fid}/freeze")
    call("GET", "/api/health", "/api/health")
    call("GET", "/api/source", "/api/source")
    call("GET", "/api/recordings", "/api/recordings")
    call("GET", "/api/checks", "/api/checks")
    call("GET", "/api/options", "/api/options")
    call("DELETE", "/api/measurements/{mid}", f"/api/measurements/{mid}")
    json_routes = {(m, p) for m, p, op in _operations(spec) if "application/json" in op["responses"]["200"]["content"]}
    # POST /api/recordings writes a recording and /api/source/replay needs a replay: their models are
    # RecordingStatusOut (checked through GET /api/recordings) and ReplayStatusOut (in /api/source);
    # POST /api/source, which switches the source, answers SourceStatusOut like GET /api/source;
    # POST /api/checks needs a board in view: CheckOut is checked in tests/service/test_service_checks.py
    assert json_routes - checked == {("POST", "/api/recordings"), ("POST", "/api/source/replay"), ("POST", "/api/source"),
                                     ("POST", "/api/checks")}


def test_extra_fields_in_a_frame_answer_are_caught():
    """The check above can fail: an answer with a key the model does not declare is refused."""
    good = {"id": 1, "uid": "u", "width": 2, "height": 2, "timestamp": 0.0, "received": 0.0, "frozen": False,
            "source": "sim", "meta": {}, "truth": None, "has_confidence": False, "replay_index": None, "recording": ""}
    schemas.FrameOut.model_validate(good)
    with pytest.raises(ValueError):
        schemas.FrameOut.model_validate({**good, "depth": 3})


def test_request_options_are_the_measuring_options():
    """Every MeasureOptions field is in OptionsIn with the same default, and nothing else is."""
    core = {f.name: f.default for f in dataclasses.fields(MeasureOptions)}
    api = {name: field.default for name, field in OptionsIn.model_fields.items()}
    assert api == core
    assert MeasureOptions(**OptionsIn().model_dump()) == MeasureOptions()


def test_click_px_is_bounded_like_the_measuring_options():
    from pydantic import ValidationError

    from measure.types import MAX_CLICK_PX

    assert MeasureOptions(**OptionsIn(click_px=0).model_dump()).click_px == 0.0
    assert OptionsIn(click_px=MAX_CLICK_PX).click_px == MAX_CLICK_PX
    for bad in (-1.0, MAX_CLICK_PX + 0.5, float("nan"), float("inf")):
        with pytest.raises(ValidationError, match="click_px"):
            OptionsIn(click_px=bad)


def test_serve_help_states_the_settings_defaults():
    """``depthruler serve --help`` says the defaults ServerConfig (the one settings object) has: each
    ``{field}`` in a flag's help names a ServerConfig field, and the rendered help shows its value."""
    import inspect
    import re

    from typer.testing import CliRunner

    from cli.main import app
    from cli.serve import serve
    from service.config import ServerConfig

    defaults = ServerConfig()
    shown = " ".join(CliRunner().invoke(app, ["serve", "--help"], env={"COLUMNS": "400"}).output.split())
    checked = 0
    for param in inspect.signature(serve).parameters.values():
        for name in re.findall(r"\{(\w+)\}", getattr(param.default, "help", "") or ""):
            assert name in ServerConfig.model_fields, name
            assert f"the config's or {getattr(defaults, name)}" in shown, (name, getattr(defaults, name))
            checked += 1
    assert checked >= 3  # host, port, ring_size


def test_create_app_takes_one_settings_object(tmp_path):
    from service.config import ServerConfig

    settings = ServerConfig(db=str(tmp_path / "h.db"), ring_size=5, keep_viewed=2, history_max_gb=0.5)
    app = create_app(SIM, settings)
    state = app.state.service
    assert state.ring.capacity == 5 and state.store.max_bytes == 500_000_000
    assert state.recorder.root == tmp_path / "recordings"
    again = create_app(SIM, db_path=tmp_path / "h.db", ring_size=5, keep_viewed=2, history_max_bytes=500_000_000)
    assert again.state.service.ring.capacity == 5 and again.state.service.store.max_bytes == 500_000_000
    with pytest.raises(ValueError, match="ring_sise"):
        create_app(SIM, db_path=tmp_path / "h.db", ring_sise=5)
    for a in (app, again):
        a.state.service.store.close()
