"""The service under attack: paths outside the recordings root, cross-site requests, a rebinding Host,
huge bodies and integers, long-polls that would starve the workers, and serving exposed without a token."""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from fastapi.testclient import TestClient
from factories import PlaneSource
from server_process import free_port
from service_client import latest, make_client, measure

from service.app import create_app

# serve's default port 8000 held meanwhile: none of these depends on it (tests/integration/test_busy_default_port.py)
pytestmark = pytest.mark.usefixtures("port_8000_held")

ORIGIN = "http://127.0.0.1"  # make_client's base URL: the page's own origin


@pytest.mark.parametrize("out", ["../escape", "../../x", "{tmp}/abs", "a/b", "..", ".", "a\\b", "", " x", "x" * 200, "evil\n", "evil\r\n"])
def test_recording_out_is_a_plain_name_inside_the_root(tmp_path, monkeypatch, out):
    (tmp_path / "cwd").mkdir()
    monkeypatch.chdir(tmp_path / "cwd")  # had the server followed the path, it lands under tmp_path
    out = out.format(tmp=tmp_path)
    with make_client(tmp_path, capture_fps=50.0) as c:
        latest(c)
        r = c.post("/api/recordings", json={"action": "start", "out": out})
        assert r.status_code == 422, r.text
        assert "plain folder name" in r.text
        assert not c.get("/api/recordings").json()["active"]
    assert {p.name for p in tmp_path.iterdir()} <= {"cwd", "h-frames", "h.db", "h.db-shm", "h.db-wal"}
    assert list((tmp_path / "cwd").iterdir()) == []


def test_recording_into_a_link_that_leads_out_of_the_root_is_refused(tmp_path):
    root, outside = tmp_path / "recs", tmp_path / "outside"
    root.mkdir()
    outside.mkdir()
    (root / "link").symlink_to(outside)
    with make_client(tmp_path, capture_fps=50.0, recordings_dir=root) as c:
        latest(c)
        r = c.post("/api/recordings", json={"action": "start", "out": "link"})
        assert r.status_code == 422 and "leads out of" in r.json()["detail"], r.text
        assert not c.get("/api/recordings").json()["active"]
    assert list(outside.iterdir()) == []


def test_recording_goes_under_the_configured_root(tmp_path):
    root = tmp_path / "recs"
    with make_client(tmp_path, capture_fps=50.0, recordings_dir=root) as c:
        latest(c)
        r = c.post("/api/recordings", json={"action": "start", "out": "session-1"})
        assert r.status_code == 200, r.text
        assert r.json()["path"] == str(root / "session-1")
        c.post("/api/recordings", json={"action": "stop"})
        auto = c.post("/api/recordings", json={"action": "start"}).json()["path"]
        c.post("/api/recordings", json={"action": "stop"})
    assert (root / "session-1" / "manifest.json").exists()
    assert auto.startswith(str(root) + "/")


def test_cross_site_state_changes_are_403(tmp_path):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        json_ct = {"Content-Type": "application/json"}
        for headers in (
            {"Origin": "http://evil.example", **json_ct},
            {"Origin": "null", **json_ct},
            {"Origin": "http://127.0.0.1:9999", **json_ct},  # another port is another origin
            {"Sec-Fetch-Site": "cross-site", **json_ct},
            {"Sec-Fetch-Site": "same-site", **json_ct},
        ):
            for method, url in (("POST", f"/api/frames/{fid}/freeze"), ("DELETE", f"/api/frames/{fid}/freeze")):
                r = c.request(method, url, headers=headers)
                assert r.status_code == 403, (method, headers, r.text)
                assert "cross-site" in r.json()["detail"]
        assert not c.get(f"/api/frames/{fid}").json()["frozen"]
        same = c.post(f"/api/frames/{fid}/freeze", headers={"Origin": ORIGIN, "Sec-Fetch-Site": "same-origin", **json_ct})
        assert same.status_code == 200 and same.json()["frozen"]
        assert c.get("/api/source", headers={"Origin": "http://evil.example"}).status_code == 200  # reads are CORS's job


def test_post_without_json_content_type_is_415(tmp_path):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        for ct in (None, "text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=x"):
            headers = {"Content-Type": ct} if ct else {}
            r = c.post(f"/api/frames/{fid}/freeze", headers=headers)
            assert r.status_code == 415, (ct, r.text)
        body = f'{{"frame_id": {fid}, "p1": [10, 10], "p2": [100, 10]}}'
        assert c.post("/api/measure", content=body, headers={"Content-Type": "text/plain"}).status_code == 415
        assert c.post("/api/measure", content=body, headers={"Content-Type": "application/json; charset=utf-8"}).status_code == 200


def test_foreign_host_header_is_refused(tmp_path):
    with make_client(tmp_path) as c:
        assert c.get("/api/health", headers={"Host": "127.0.0.1:8000"}).status_code == 200
        assert c.get("/api/health", headers={"Host": "localhost"}).status_code == 200
        for host in ("evil.example", "evil.example:8000", "127.0.0.1.evil.example"):
            r = c.get("/api/health", headers={"Host": host})
            assert r.status_code == 400 and "host" in r.json()["detail"].lower(), host
            assert c.get("/", headers={"Host": host}).status_code == 400


def test_host_with_a_port_that_is_not_a_number_is_refused(tmp_path):
    with make_client(tmp_path) as c:
        for host in ("127.0.0.1:evil.com", "localhost:80:81", "[::1]:evil", "127.0.0.1:"):
            r = c.get("/api/health", headers={"Host": host})
            assert r.status_code == 400 and "host" in r.json()["detail"].lower(), host
        assert c.get("/api/health", headers={"Host": "[::1]:8000"}).status_code == 200


def test_repeated_host_or_origin_headers_are_refused(tmp_path):
    """Which of two Host (or Origin) headers a reader takes is not defined: one of them is a lie."""
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        for headers in (
            [("Host", "127.0.0.1"), ("Host", "evil.example")],
            [("Host", "evil.example"), ("Host", "127.0.0.1")],
            [("Host", "127.0.0.1"), ("Origin", "http://evil.example"), ("Origin", "http://127.0.0.1")],
        ):
            raw = [(k.lower().encode(), v.encode()) for k, v in headers]
            r = c.post(f"/api/frames/{fid}/freeze", headers=httpx.Headers(raw + [(b"content-type", b"application/json")]))
            assert r.status_code == 400 and "headers; send one" in r.json()["detail"], (headers, r.text)
        assert not c.get(f"/api/frames/{fid}").json()["frozen"]


def test_malformed_json_says_where_it_breaks(tmp_path):
    with make_client(tmp_path) as c:
        latest(c)
        r = c.post("/api/measure", content=b'{"frame_id": 1, "p1": [1, 2],}', headers={"Content-Type": "application/json"})
        assert r.status_code == 422
        detail = r.json()["detail"]
        assert detail.startswith("body: the body is not valid JSON at character ") and "send a JSON object" in detail, detail
        assert "(got {})" not in detail


def test_allowed_hosts_wildcard(tmp_path):
    with make_client(tmp_path, allowed_hosts=("*",)) as c:
        assert c.get("/api/health", headers={"Host": "ruler.lab.example"}).status_code == 200


def test_body_over_limit_is_413_before_parsing(tmp_path):
    with make_client(tmp_path) as c:
        fid = latest(c)["id"]
        ct = {"Content-Type": "application/json"}
        big = b'{"frame_id": 1, "p1": [1, 1], "p2": [2, 2], "pad": "' + b"x" * 1_000_000 + b'"}'
        r = c.post("/api/measure", content=big, headers=ct)
        assert r.status_code == 413 and "bytes" in r.json()["detail"]

        def chunks():  # no Content-Length: the limit counts streamed bytes
            for _ in range(64):
                yield b"x" * 16384

        r = c.post("/api/measure", content=chunks(), headers=ct)
        assert r.status_code == 413
        # a declared length over the limit is refused without reading the body at all
        seen = []

        def lying():
            seen.append(1)
            yield b"{}"

        r = c.post("/api/measure", content=lying(), headers={**ct, "Content-Length": str(50 * 2**20)})
        assert r.status_code == 413
        assert measure(c, fid, (10, 10), (100, 10), method="basic").status_code == 200


@pytest.mark.parametrize(
    "method, url, body",
    [
        ("GET", f"/api/measurements/{2**63}", None),
        ("GET", f"/api/measurements/{2**64 + 5}/thumb.png", None),
        ("DELETE", f"/api/measurements/{2**63}", None),
        ("POST", f"/api/measurements/{2**63}/open", None),
        ("GET", f"/api/measurements?limit={2**63}", None),
        ("GET", f"/api/frames/{2**63}", None),
        ("GET", f"/api/frames/{2**63}/color.png", None),
        ("POST", f"/api/frames/{2**63}/freeze", None),
        ("GET", f"/api/frames/latest?after={2**63}", None),
        ("POST", "/api/measure", {"frame_id": 2**63, "p1": [1, 1], "p2": [5, 5]}),
        ("POST", "/api/measure", {"frame_id": 1, "p1": [1, 1], "p2": [5, 5], "options": {"seed": 2**64}}),
    ],
)
def test_huge_integers_are_422(tmp_path, method, url, body):
    with make_client(tmp_path) as c:
        latest(c)
        r = c.request(method, url, json=body, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text
        assert c.get("/api/health").status_code == 200


@pytest.mark.slow
def test_long_polls_do_not_starve_the_workers(tmp_path):
    """60 clients long-poll a source that delivers nothing; health and reads still answer meanwhile."""
    state = {"gate": threading.Semaphore(0)}
    with make_client(tmp_path, factory=lambda: PlaneSource(state=state), max_waiters=100) as c:
        with ThreadPoolExecutor(60) as pool:
            waits = [pool.submit(c.get, "/api/frames/latest", params={"wait": 8}) for _ in range(60)]
            time.sleep(1.0)  # let them all block
            assert c.get("/api/health").status_code == 200
            assert c.get("/api/source").status_code == 200
            assert not any(w.done() for w in waits)  # answered while every long-poll still waits
            state["gate"].release(1)
            answers = [w.result() for w in waits]
        assert all(a.status_code == 200 for a in answers)


def test_too_many_waiters_is_429(tmp_path):
    state = {"gate": threading.Semaphore(0)}
    with make_client(tmp_path, factory=lambda: PlaneSource(state=state), max_waiters=4) as c:
        with ThreadPoolExecutor(4) as pool:
            waits = [pool.submit(c.get, "/api/frames/latest", params={"wait": 8}) for _ in range(4)]
            deadline = time.monotonic() + 10
            while c.app.state.ring.waiters < 4 and time.monotonic() < deadline:
                time.sleep(0.01)
            r = c.get("/api/frames/latest", params={"wait": 1})
            assert r.status_code == 429 and "Retry-After" in r.headers
            state["gate"].release(1)
            assert all(w.result().status_code == 200 for w in waits)


def test_exposed_without_token_refuses_to_start(tmp_path, monkeypatch):
    import uvicorn
    from typer.testing import CliRunner

    from cli.main import app

    calls = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: calls.update(app=app, **kw))
    monkeypatch.delenv("DEPTHRULER_TOKEN", raising=False)
    args = ["serve", "--source", "sim", "--host", "0.0.0.0", "--port", str(free_port()), "--db", str(tmp_path / "o.db")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "--token" in result.output and "--insecure-no-token" in result.output
    assert not calls
    result = CliRunner().invoke(app, [*args, "--insecure-no-token"])
    assert result.exit_code == 0, result.output
    assert calls["host"] == "0.0.0.0" and "anyone on the network" in result.output


def test_recordings_flag_sets_the_root(tmp_path, monkeypatch):
    import uvicorn
    from typer.testing import CliRunner

    from cli.main import app

    calls = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: calls.update(app=app, **kw))
    args = ["serve", "--source", "sim", "--port", str(free_port()), "--db", str(tmp_path / "o.db"), "--recordings", str(tmp_path / "r"),
            "--history-max-gb", "0.5"]  # fmt: skip
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert calls["app"].state.recorder.root == (tmp_path / "r").resolve()
    assert calls["app"].state.store.max_bytes == 500_000_000


def test_default_client_sees_localhost_only(tmp_path):
    """A TestClient's default host 'testserver' is not a bound name: the default allows loopback only."""
    with TestClient(create_app(PlaneSource, db_path=tmp_path / "h.db")) as c:
        assert c.get("/api/health").status_code == 400
