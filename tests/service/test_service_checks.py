"""``POST /api/checks``: the board check on a frozen frame of the simulator's ChArUco board, its picture, the
history it joins, and the typed refusals (no board in view, a wrong board, a frame gone, a bad id)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from history.checks import checks_path, read_checks
from service.app import create_app
from service.board_check import frames_note
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
    assert rec["frames_requested"] == 3 and "frames_note" not in rec


def test_fewer_frames_than_asked_are_used_and_said(tmp_path):
    """The first frame of a stream has none before it: a 3-frame check on it checks that one and says so,
    in its answer and in the checks log the page's history reads."""
    db = tmp_path / "h.db"
    with TestClient(create_app(SPEC.replace("fps=10", "fps=2"), db_path=db, ring_size=64), base_url="http://127.0.0.1") as c:
        assert c.get("/api/frames/latest", params={"wait": 10}).status_code == 200
        assert c.post("/api/frames/1/freeze", headers=JSON).status_code == 200  # 32 s in the ring at 2 fps, frozen now
        r = c.post("/api/checks", json={"frame_id": 1, "frames": 3})
    assert r.status_code == 200, r.text
    rec = CheckOut.model_validate(r.json())
    assert rec.frame_ids == [1] and rec.frames_requested == 3 and rec.figures["frames_with_board"] == 1
    assert rec.frames_note == "used 1 of 3 frames: the ring held no earlier frame of this camera before frame 1"
    assert read_checks(checks_path(db))[0]["frames_note"] == rec.frames_note
    assert frames_note(2, 3, 17) == "used 2 of 3 frames: the ring held only 1 earlier frame of this camera before frame 17"
    assert frames_note(4, 5, 9).startswith("used 4 of 5 frames: the ring held only 3 earlier frames") and frames_note(3, 3, 9) is None


def test_refusals_say_what_to_change(client):
    fid = frozen(client)
    wrong = client.post("/api/checks", json={"frame_id": fid, "board": {"squares_x": 11, "squares_y": 8}})
    assert wrong.status_code == 422 and "no 11x8 ChArUco board" in wrong.json()["detail"]
    bad = client.post("/api/checks", json={"frame_id": fid, "board": {"square_mm": 20, "marker_mm": 30}})
    assert bad.status_code == 422 and "marker side" in bad.json()["detail"]
    assert client.post("/api/checks", json={"frame_id": 10**9}).status_code == 404
    assert client.get("/api/checks/../check.png").status_code == 404
    assert client.get("/api/checks/abcdef/check.png").status_code == 404
