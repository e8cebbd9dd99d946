"""``POST /api/checks``: the board check on a frozen frame of the simulator's ChArUco board, its picture, the
history it joins, and the typed refusals (no board in view, a wrong board, a frame gone, a bad id)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from history.checks import checks_path, read_checks
from service.app import create_app
from service.schemas import CheckOut

SPEC = "sim:charuco?distance=1.2&width=640&height=360&fps=10"
JSON = {"Content-Type": "application/json"}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    db = tmp_path_factory.mktemp("checks") / "h.db"
    with TestClient(create_app(SPEC, db_path=db, ring_size=8), base_url="http://127.0.0.1") as c:
        c.db = db
        yield c


def frozen(c) -> int:
    fid = c.get("/api/frames/latest", params={"wait": 5}).json()["id"]
    assert c.post(f"/api/frames/{fid}/freeze", headers=JSON).status_code == 200
    return fid


def test_the_check_on_a_frozen_frame_gives_its_figures_picture_and_history(client):
    fid = frozen(client)
    r = client.post("/api/checks", json={"frame_id": fid})
    assert r.status_code == 200, r.text
    rec = r.json()
    CheckOut.model_validate(rec)
    assert rec["frame_ids"] == [fid] and rec["board"]["squares_x"] == 7 and rec["board"]["square_mm"] == 40.0
    fig = rec["figures"]
    assert fig["pairs"] >= 20 and fig["distance_m"] == pytest.approx(1.2, rel=0.02)  # the scene's board, where it stands
    assert abs(fig["bias_pct"]) < 2.0 and rec["status"] in ("ok", "check", "poor") and rec["findings"]
    png = client.get("/" + rec["png_url"])
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    img = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[0] > 200
    listed = client.get("/api/checks").json()
    assert listed["checks"][0]["id"] == rec["id"] and listed["checks"][0]["figures"]["pairs"] == fig["pairs"]
    assert read_checks(checks_path(client.db))[0]["png_url"] == rec["png_url"]


def test_more_frames_and_an_explicit_board(client):
    fid = frozen(client)
    board = {"squares_x": 7, "squares_y": 5, "square_mm": 40, "marker_mm": 30, "dictionary": "DICT_5X5_100"}
    rec = client.post("/api/checks", json={"frame_id": fid, "frames": 3, "board": board}).json()
    assert len(rec["frame_ids"]) == 3 and rec["frame_ids"][-1] == fid and rec["figures"]["frames_with_board"] == 3


def test_refusals_say_what_to_change(client):
    fid = frozen(client)
    wrong = client.post("/api/checks", json={"frame_id": fid, "board": {"squares_x": 11, "squares_y": 8}})
    assert wrong.status_code == 422 and "no 11x8 ChArUco board" in wrong.json()["detail"]
    bad = client.post("/api/checks", json={"frame_id": fid, "board": {"square_mm": 20, "marker_mm": 30}})
    assert bad.status_code == 422 and "marker side" in bad.json()["detail"]
    assert client.post("/api/checks", json={"frame_id": 10**9}).status_code == 404
    assert client.get("/api/checks/../check.png").status_code == 404
    assert client.get("/api/checks/abcdef/check.png").status_code == 404
