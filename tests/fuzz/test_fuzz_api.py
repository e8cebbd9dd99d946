"""Fuzzing the HTTP API with schemathesis: requests generated from the OpenAPI schema of
``service.app.create_app`` on a small ``sim`` source, sent in-process through one ASGI test client.

Every request is answered: a 2xx, or a 4xx whose JSON ``detail`` says what to change; never a 5xx.
The app and its schema are built when the test runs, not at collection. POST /api/recordings is
left out: its ``out`` field names a folder, and generated names would fill the recordings root.
"""

from __future__ import annotations

import httpx
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings

SPEC = "sim:poster?width=160&height=120&fps=0&seed=1"


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    from service.app import create_app

    return create_app(SPEC, db_path=tmp_path_factory.mktemp("api-fuzz") / "api.db", capture_fps=20.0, ring_size=8)


@pytest.fixture(scope="module")
def client(app):
    """The app running (its lifespan starts the capture thread, which fills the ring) with a frame to
    measure on. Requests go through this one client: schemathesis' own ASGI client would run the
    lifespan per request, and its end closes the store."""
    with TestClient(app, base_url="http://127.0.0.1", raise_server_exceptions=False) as c:  # a server error is a 500 answer
        assert c.get("/api/frames/latest", params={"wait": 10}).status_code == 200
        yield c


def _send(client: TestClient, case) -> httpx.Response:
    kw = case.as_transport_kwargs(base_url="http://127.0.0.1")
    data = kw.pop("data", None)
    if isinstance(data, (bytes, str)):
        kw["content"] = data
    elif data is not None:
        kw["data"] = data
    kw.pop("files", None)
    client.cookies.clear()
    client.cookies.update(kw.pop("cookies", None) or {})
    return client.request(**{k: v for k, v in kw.items() if k in ("method", "url", "params", "headers", "json", "content", "data")})


def _check(client: TestClient, case) -> None:
    if isinstance(case.body, dict) and "frame_id" in case.body and int(case.id, 36) % 2:
        # Half the measure requests on a frame that exists, so the measuring path is fuzzed too.
        case.body["frame_id"] = client.get("/api/frames/latest").json()["id"]
    if isinstance(case.query, dict) and isinstance(case.query.get("wait"), (int, float)):
        case.query["wait"] = min(case.query["wait"], 0.2)  # a long poll: keep the budget small
    response = _send(client, case)
    what = f"{case.method} {case.formatted_path} {case.query or ''} {case.body!r:.200}"
    assert response.status_code < 500, f"{what} -> {response.status_code}: {response.text[:300]}"
    if 400 <= response.status_code < 500 and "json" in response.headers.get("content-type", ""):
        assert response.json().get("detail"), f"{what} -> {response.status_code} without a detail message"


@pytest.mark.slow
def test_api_answers_every_request_without_a_server_error(app, client):
    import schemathesis  # here, not at collection, which every run of the fast loop (leaving this test out) pays

    schema = schemathesis.openapi.from_dict(app.openapi()).exclude(method="POST", path="/api/recordings")
    examples = max(5, settings.default.max_examples // 4)  # per operation: a quarter of the profile's
    failures = []
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 20  # every route of the API, less the one left out
    for operation in operations:

        @settings(max_examples=examples, suppress_health_check=list(HealthCheck))
        @given(case=operation.as_strategy())
        def one(case) -> None:
            _check(client, case)

        try:
            one()
        except AssertionError as exc:
            failures.append(f"{operation.label}: {exc}")
    assert not failures, "\n".join(failures)
