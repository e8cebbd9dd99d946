"""The service app on a fake source in a TestClient, and the requests the API tests repeat."""

from __future__ import annotations

from fastapi.testclient import TestClient

from factories import PlaneSource
from service.app import create_app

BASE = "http://127.0.0.1"  # a loopback Host, as a browser on this machine sends
JSON = {"Content-Type": "application/json"}  # every POST says JSON, body or not (cross-site forms cannot)


def make_client(tmp_path, factory=PlaneSource, **kw) -> TestClient:
    """The app on ``factory`` (a callable returning an unopened source), its history in ``tmp_path``;
    fast capture and reconnects unless ``kw`` say otherwise."""
    kw.setdefault("capture_fps", 200.0)
    kw.setdefault("reconnect_initial_s", 0.02)
    kw.setdefault("reconnect_max_s", 0.1)
    return TestClient(create_app(factory, db_path=tmp_path / "h.db", **kw), base_url=BASE)


def latest(client: TestClient, after: int = 0) -> dict:
    """The newest frame after id ``after`` (waits up to 5 s)."""
    r = client.get("/api/frames/latest", params={"after": after, "wait": 5})
    assert r.status_code == 200, r.text
    return r.json()


def measure(client, fid, p1, p2, **options):
    return client.post("/api/measure", json={"frame_id": fid, "p1": list(p1), "p2": list(p2), "options": options})


def frame_index(client, f) -> int:
    """The fake source's frame number of the served frame ``f`` (from its meta)."""
    return client.get(f"/api/frames/{f['id']}").json()["meta"]["index"]
