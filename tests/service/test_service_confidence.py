"""The confidence view and the weak stretch through the API: ``confidence.png`` is the frame's
matcher confidence (grey, round(c * 255)), darker on the simulator's textureless wall than on the poster
glued to it (SGBM on the rendered pair, ``sim:plain-wall?mode=stereo``); a measurement says where
along its segment the support is weak; a source without confidence answers a 404 that says which do."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from device import open_source
from measure.confidence import LOW_CONFIDENCE, LOW_CONFIDENCE_REASON
from service.app import create_app
from service_client import BASE, latest, measure

WALL = "sim:plain-wall?mode=stereo&width=320&height=180&distance=2.5&fps=20&seed=3"


def client(tmp_path, spec: str) -> TestClient:
    return TestClient(create_app(spec, db_path=tmp_path / "h.db", capture_fps=20.0, ring_size=4), base_url=BASE)


def truth_px(spec: str, target: str) -> tuple[list[float], list[float]]:
    """The clicks of ``target`` in ``spec``'s scene (the truth is geometry: the same for every frame)."""
    with open_source(f"{spec}&target={target}") as src:
        t = src.read(timeout_s=30).meta["truth"]
    return [float(v) for v in t.p1_px], [float(v) for v in t.p2_px]


def inset(p1, p2, share: float):
    """The segment p1 -> p2 shortened by ``share`` of its length at each end."""
    a, b = np.asarray(p1), np.asarray(p2)
    return (a + share * (b - a)).tolist(), (b - share * (b - a)).tolist()


def band(img: np.ndarray, p1, p2, half: int = 3) -> np.ndarray:
    """The pixels of a horizontal segment's band, ``half`` rows either side."""
    y, x0, x1 = int(round(p1[1])), int(round(min(p1[0], p2[0]))), int(round(max(p1[0], p2[0])))
    return img[y - half : y + half + 1, x0 : x1 + 1]


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    with client(tmp_path_factory.mktemp("wall"), WALL) as c:
        f = latest(c)
        yield c, f, c.app.state.service.ring.get(f["id"]).frame


def test_confidence_png_is_the_frames_confidence(wall):
    c, f, frame = wall
    assert f["has_confidence"] is True
    r = c.get(f"/api/frames/{f['id']}/confidence.png")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png" and r.content[:8] == b"\x89PNG\r\n\x1a\n"
    img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img.shape == (f["height"], f["width"]) and img.dtype == np.uint8  # one grey channel, the frame's size
    np.testing.assert_array_equal(img, np.rint(np.clip(frame.confidence, 0, 1) * 255).astype(np.uint8))
    # black where the wall has no texture for SGBM, bright on the printed poster beside it
    wall_px, poster_px = truth_px(WALL, "wall-width"), truth_px(WALL, "poster-width")
    on_wall, on_poster = band(img, *wall_px).astype(float) / 255, band(img, *inset(*poster_px, 0.1)).astype(float) / 255
    print(f"confidence.png mean: wall {on_wall.mean():.3f}, poster {on_poster.mean():.3f}")
    assert on_wall.mean() < LOW_CONFIDENCE < on_poster.mean()
    assert on_poster.mean() - on_wall.mean() > 0.5


def test_a_wall_segment_is_weak_along_most_of_it_and_the_poster_nowhere(wall):
    c, f, _ = wall
    on_wall = measure(c, f["id"], *truth_px(WALL, "wall-width"))
    assert on_wall.status_code == 200, on_wall.text
    m = on_wall.json()
    weak = np.array(m["weak_stretches"])
    covered = float((weak[:, 1] - weak[:, 0]).sum())
    print(f"wall segment: weak stretches {m['weak_stretches']} ({covered:.0%} of it), reasons {m['reasons']}")
    assert covered >= 0.9 and (weak >= 0).all() and (weak <= 1).all() and (np.diff(weak.ravel()) > 0).all()
    assert LOW_CONFIDENCE_REASON in m["reasons"] and m["quality"] != "good"
    # kept with the measurement: the history gives the same stretches back
    assert c.get(f"/api/measurements/{m['id']}").json()["weak_stretches"] == m["weak_stretches"]

    on_poster = measure(c, f["id"], *inset(*truth_px(WALL, "poster-width"), 0.1))
    assert on_poster.status_code == 200, on_poster.text
    p = on_poster.json()
    assert p["weak_stretches"] == [] and LOW_CONFIDENCE_REASON not in p["reasons"]


def test_a_source_without_confidence_says_so(tmp_path):
    with client(tmp_path, "sim:boxes?confidence=false&width=320&height=180&fps=20") as c:
        f = latest(c)
        assert f["has_confidence"] is False
        r = c.get(f"/api/frames/{f['id']}/confidence.png")
        assert r.status_code == 404 and r.headers["content-type"] == "application/json"
        detail = r.json()["detail"]
        assert f"frame {f['id']} has no confidence map" in detail and "mode=stereo" in detail and "align=left" in detail
        m = measure(c, f["id"], (100.0, 90.0), (200.0, 90.0))
        assert m.status_code == 200 and m.json()["weak_stretches"] == []
        unknown = c.get("/api/frames/987654/confidence.png")
        assert unknown.status_code == 404 and "does not exist" in unknown.json()["detail"]
