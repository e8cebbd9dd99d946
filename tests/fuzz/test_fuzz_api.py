"""Fuzzing the HTTP API (issue 22) with schemathesis: requests generated from the OpenAPI schema of
``service.app.create_app`` on a small ``sim`` source, sent in-process through one ASGI test client.

Every request is answered: a 2xx, or a 4xx whose JSON ``detail`` says what to change; never a 5xx.
POST /api/recordings is left out: its ``out`` field is a server path, and generated paths would
write recordings anywhere on this machine (see the report of issue 22).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pytest
from hypothesis import settings

schemathesis = pytest.importorskip("schemathesis")  # the `test` extra; skip where it is not installed

import httpx  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from service.app import create_app  # noqa: E402

SPEC = "sim:poster?width=160&height=120&fps=0&seed=1"
# schemathesis.pytest.from_fixture does not work with pytest 9 (it reads Function._nodeid), so the app
# and its schema are built at import.
_DB_DIR = tempfile.mkdtemp(prefix="depthruler-api-fuzz-")
APP = create_app(SPEC, db_path=Path(_DB_DIR) / "api.db", capture_fps=20.0, ring_size=8)
# From the app's schema itself: loading it over ASGI would run (and end) the app's lifespan, which
# closes its store for good.
schema = schemathesis.openapi.from_dict(APP.openapi()).exclude(method="POST", path="/api/recordings")


@pytest.fixture(scope="module")
def client():
    """The app running (its lifespan starts the capture thread, which fills the ring) with a frame to
    measure on. Requests go through this one client: schemathesis' own ASGI client would run the
    lifespan per request, and its end closes the store."""
    with TestClient(APP, base_url="http://127.0.0.1", raise_server_exceptions=False) as c:  # a server error is a 500 answer
        assert c.get("/api/frames/latest", params={"wait": 10}).status_code == 200
        yield c
    shutil.rmtree(_DB_DIR, ignore_errors=True)


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


# Found by this test on 2026-12-01 and left to the engineer rewriting service/ (issue 22). A request that
# hits one of them ends the operation's test as xfail, so every other operation stays guarded.
KNOWN = (
    (lambda case, r: r.status_code == 500 and any(_big(v) for v in [*(case.path_parameters or {}).values(), *(case.query or {}).values()]),
     "history/store.py: a measurement id (/api/measurements/{mid}) or ?limit= beyond SQLite's 64-bit INTEGER "
     "raises OverflowError (500); the routes should bound them (404 or 422)"),
)
# Also found, and kept out of the generated requests because it depends on timing (a flaky answer):
# GET /api/frames/latest?after=N&wait=W answers 503 when no frame newer than N arrives within W, e.g.
# for an `after` beyond the newest id; a long-poll timeout is not a server failure (204, or 404/422).


def _big(value: object) -> bool:
    return isinstance(value, int) and not -(2**63) <= value < 2**63


@schema.parametrize()
@settings(max_examples=max(5, settings.default.max_examples // 4))  # per operation: a quarter of the profile's
def test_api_answers_every_request_without_a_server_error(client, case):
    if isinstance(case.body, dict) and "frame_id" in case.body and int(case.id, 36) % 2:
        # Half the measure requests on a frame that exists, so the measuring path is fuzzed too.
        case.body["frame_id"] = client.get("/api/frames/latest").json()["id"]
    if isinstance(case.query, dict) and isinstance(case.query.get("wait"), (int, float)):
        case.query["wait"] = min(case.query["wait"], 0.2)  # a long poll: keep the budget small
    if case.path == "/api/frames/latest" and isinstance(case.query, dict) and isinstance(case.query.get("after"), int):
        case.query["after"] = min(case.query["after"], client.get("/api/frames/latest").json()["id"] - 1)  # see above
    response = _send(client, case)
    what = f"{case.method} {case.formatted_path} {case.query or ''} {case.body!r:.200}"
    for known, reason in KNOWN:
        if known(case, response):
            pytest.xfail(reason)
    assert response.status_code < 500, f"{what} -> {response.status_code}: {response.text[:300]}"
    if 400 <= response.status_code < 500 and "json" in response.headers.get("content-type", ""):
        assert response.json().get("detail"), f"{what} -> {response.status_code} without a detail message"
