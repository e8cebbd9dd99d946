"""The measuring tools in a real browser: distance, path, area, height and box, by mouse at 1366x800
and by touch at 390x844. `depthruler serve` on the simulated boxes (two 0.5 x 0.4 x 0.6 m boxes on a
floor, 1.2 m away, a static scene): each tool's points go where the scene's truth says, the value
on screen is the one stored (GET /api/measurements/{id}), the box's dimensions and the height are
the scene's, undo takes back the last point, and a shape reopened from the history is drawn again
from its stored ``draw_px``."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest

from browser_helpers import open_live, serve, watch
from sim.scenes import SceneParams, get_view

SPEC = "sim:boxes?distance=1.2&contention=0&seed=3&fps=5"  # no wrong-pair matches: every frame of 80 measured
VIEWPORTS = {"mouse": dict(viewport={"width": 1366, "height": 800}),
             "touch": dict(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True, device_scale_factor=2)}

pytestmark = [pytest.mark.browser, pytest.mark.slow]


class Scene:
    """Where each tool's points go on the right-hand box, and the truth there (the ray-cast view)."""

    def __init__(self) -> None:
        self.view = get_view(SceneParams("boxes", 1.2))
        box = next(p for p in self.view.spec.prims if getattr(p, "obj", "") == "box-right")
        c, (hx, hy, hz) = np.array(box.centre), box.half
        self.dims = (2 * max(hx, hz), 2 * min(hx, hz), 2 * hy)  # length >= width, height (m)
        self.top = self._px([c + [0, -hy, 0]])[0]  # the top face's centre
        # the front face, its corners 30 % in from the edges, in order around it
        self.front = self._px([c + [sx * hx * 0.7, sy * hy * 0.7, -hz] for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])

    def _px(self, world) -> list[list[float]]:
        return np.round(self.view.pose.project(self.view.camera, np.array(world))).tolist()

    def point(self, px) -> np.ndarray:
        """The true 3D point (camera frame, m) seen at pixel ``px``."""
        x, y = int(px[0]), int(px[1])
        cam, z = self.view.camera, self.view.depth[y, x]
        return np.array([(x - cam.cx) / cam.fx * z, (y - cam.cy) / cam.fy * z, z])

    def path_m(self, pts) -> float:
        return float(sum(np.linalg.norm(self.point(b) - self.point(a)) for a, b in zip(pts, pts[1:])))

    def area_m2(self, pts) -> float:
        q = [self.point(p) for p in pts]
        return float(sum(np.linalg.norm(np.cross(q[i] - q[0], q[i + 1] - q[0])) / 2 for i in range(1, len(q) - 1)))


@pytest.fixture(scope="module")
def scene():
    return Scene()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("tools"), SPEC) as base:
        yield base


class Hand:
    """Presses on the page as a mouse or a finger (CDP touch events: pointerType "touch")."""

    def __init__(self, page, how: str) -> None:
        self.page, self.how = page, how
        self.cdp = page.context.new_cdp_session(page) if how == "touch" else None

    def press(self, selector: str) -> None:
        loc = self.page.locator(selector)
        loc.tap() if self.how == "touch" else loc.click()

    def place(self, frame: dict, px) -> None:
        """A press and release on image pixel ``px`` (pixel-centre convention) of the unzoomed canvas."""
        box = self.page.locator("#canvas").bounding_box()
        x = box["x"] + (px[0] + 0.5) * box["width"] / frame["width"]
        y = box["y"] + (px[1] + 0.5) * box["height"] / frame["height"]
        if self.how == "mouse":
            self.page.mouse.click(x, y)
            return
        touch = [{"x": x, "y": y, "radiusX": 8, "radiusY": 8, "force": 1, "id": 1}]
        self.cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": touch})
        self.cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})


@pytest.fixture(params=list(VIEWPORTS))
def hand(request, browser, server):
    ctx = browser.new_context(**VIEWPORTS[request.param])
    page = ctx.new_page()
    watch(page)
    open_live(page, server)
    yield Hand(page, request.param)
    ctx.close()
    assert page.problems == [], "\n".join(page.problems)  # type: ignore[attr-defined]


def frozen_frame(hand: Hand, server: str) -> dict:
    hand.press("#freeze")
    hand.page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
    return httpx.get(f"{server}/api/frames/{hand.page.get_attribute('#canvas', 'data-frame-id')}").json()


def placed(page) -> list[list[float]]:
    return json.loads(page.get_attribute("#canvas", "data-points"))


def near(got, want, px: float = 1.0) -> bool:
    """Whether two lists of points agree within ``px`` image pixels each."""
    return len(got) == len(want) and bool(np.all(np.abs(np.array(got, float) - np.array(want, float)) <= px))


def choose(hand: Hand, kind: str) -> None:
    hand.press(f"#tools [data-tool={kind}]")
    assert hand.page.get_attribute(f"#tools [data-tool={kind}]", "aria-pressed") == "true"
    assert hand.page.get_attribute("#canvas", "data-tool") == kind


def test_tools_collect_points_with_undo_and_switching_clears(hand, server, scene):
    """Without measuring: each tool collects its points, Undo point takes back the last one, and
    choosing another tool starts empty; the path and area wait for Measure, which needs enough points."""
    page = hand.page
    frame = frozen_frame(hand, server)
    for kind, pts in (("path", scene.front[:3]), ("area", scene.front)):
        choose(hand, kind)
        assert placed(page) == [] and page.locator("#shape-measure").is_visible()
        for i, p in enumerate(pts):
            hand.place(frame, p)
            page.wait_for_function("n => JSON.parse(document.getElementById('canvas').dataset.points).length === n", arg=i + 1)
            ready = i + 1 >= {"path": 2, "area": 3}[kind]
            assert page.locator("#shape-measure").is_enabled() == ready, (kind, i)
        assert near(placed(page), pts)
        stray = np.mean(pts, axis=0).round().tolist()  # in the middle: no finger's reach from a placed point
        hand.place(frame, stray)  # a stray point, taken back
        page.wait_for_function("n => JSON.parse(document.getElementById('canvas').dataset.points).length === n", arg=len(pts) + 1)
        hand.press("#undo-point")
        assert near(placed(page), pts)
        assert page.get_attribute("#distance", "data-id") is None  # nothing measured yet
    choose(hand, "distance")
    assert placed(page) == [] and page.locator("#shape-measure").is_hidden() and page.locator("#undo-point").is_disabled()
    assert page.text_content("#result-title") == "Distance"


def wait_measured(page, previous: str | None) -> dict:
    """The stored measurement the card shows, once it shows one other than ``previous``."""
    page.wait_for_function(
        "prev => { const d = document.getElementById('distance').dataset; return d.id && d.id !== prev; }",
        arg=previous or "", timeout=30_000,
    )
    return {"id": page.get_attribute("#distance", "data-id")}


def shown_equals_stored(page, stored: dict) -> None:
    """The card says what the history holds: the value as text and to the last bit, its interval, the verdict."""
    kind = stored.get("kind", "segment")
    text = page.text_content("#distance")
    word = {"good": "✓ good", "check": "⚠ check", "unreliable": "✕ unreliable"}[stored["quality"]]
    assert page.text_content("#verdict") == word
    if kind == "segment":
        assert float(page.get_attribute("#distance", "data-metres")) == stored["distance_m"]
        assert text == f"{stored['distance_m']:.3f} m"
        return
    if kind == "box":
        dims = page.locator("#dims .dim")
        assert [float(dims.nth(i).get_attribute("data-metres")) for i in range(3)] == stored["dimensions_m"]
        assert [[float(dims.nth(i).get_attribute(a)) for a in ("data-low", "data-high")] for i in range(3)] == stored["dimension_intervals_m"]
        assert text == " × ".join(f"{v:.3f}" for v in stored["dimensions_m"]) + " m"
        return
    assert float(page.get_attribute("#distance", "data-value")) == stored["value"]
    assert text == f"{stored['value']:.3f} " + {"m": "m", "m2": "m²"}[stored["unit"]]
    assert [float(page.get_attribute("#interval", a)) for a in ("data-low", "data-high")] == stored["interval"]
    assert page.text_content("#interval").startswith(text)


def drawn(page) -> list:
    return json.loads(page.get_attribute("#canvas", "data-drawn"))


def test_each_tool_measures_and_shows_the_stored_value(hand, server, scene):
    """Distance, path, area, height and box in turn on one frozen frame: the value on screen is the
    stored one, and the scene's truth (box 0.5 x 0.4 x 0.6 m; the height of its top; the distance, the
    path and the area from the true depth under the clicks). By mouse the tools are chosen with their keys and a
    path or area ended with Enter; by touch with the buttons. Then two shapes reopened from the
    history come back drawn from their stored draw_px."""
    page = hand.page
    frame = frozen_frame(hand, server)
    clicks = {"distance": [scene.front[1], scene.front[3]], "path": scene.front[:3], "area": scene.front,
              "height": [scene.top], "box": [scene.top]}
    keys = {"distance": "l", "path": "p", "area": "a", "height": "h", "box": "b"}
    stored, previous = {}, None
    for kind, pts in clicks.items():
        if hand.how == "mouse":
            page.keyboard.press(keys[kind])
            assert page.get_attribute("#canvas", "data-tool") == kind
        else:
            choose(hand, kind)
        if kind == "height":  # an auto-measured point taken back: the answer goes, the point too
            hand.place(frame, pts[0])
            previous = wait_measured(page, previous)["id"]
            hand.press("#undo-point")
            assert placed(page) == [] and page.get_attribute("#distance", "data-id") is None and drawn(page) == []
        for p in pts:
            hand.place(frame, p)
        if kind in ("path", "area"):
            page.wait_for_function("n => JSON.parse(document.getElementById('canvas').dataset.points).length === n", arg=len(pts))
            page.keyboard.press("Enter") if hand.how == "mouse" else hand.press("#shape-measure")
        previous = wait_measured(page, previous)["id"]
        record = httpx.get(f"{server}/api/measurements/{previous}").json()
        stored[kind] = record
        assert record.get("kind", "segment") == ("segment" if kind == "distance" else kind)
        assert near(record["points"] if kind != "distance" else [record["p1"], record["p2"]], pts)
        shown_equals_stored(page, record)
        if kind != "distance":
            assert drawn(page) == record["draw_px"]
        print(f"{hand.how} {kind}: {page.text_content('#distance')} ({record['quality']})")

    assert stored["distance"]["distance_m"] == pytest.approx(scene.path_m(clicks["distance"]), rel=0.02)
    assert stored["path"]["value"] == pytest.approx(scene.path_m(clicks["path"]), rel=0.02)
    assert stored["area"]["value"] == pytest.approx(scene.area_m2(clicks["area"]), rel=0.03)
    assert stored["height"]["value"] == pytest.approx(scene.dims[2], rel=0.02)
    assert stored["box"]["dimensions_m"] == pytest.approx(list(scene.dims), rel=0.03)
    assert stored["path"]["unit"] == "m" and stored["area"]["unit"] == "m2"

    # reopened from the history after going live: the shape on its saved frame, with its tool
    hand.press("#freeze")
    page.wait_for_function("document.getElementById('frame-tag').textContent.startsWith('live')")
    for kind in ("box", "path"):
        record = stored[kind]
        row = page.locator(f"#history li[data-id='{record['id']}']")
        assert row.get_attribute("data-kind") == kind and row.locator(".h-meta").text_content().startswith(kind)
        row.locator(".h-dist").click() if hand.how == "mouse" else row.locator(".h-dist").tap()
        page.wait_for_function(
            "id => document.getElementById('distance').dataset.id === id && document.getElementById('canvas').dataset.frozen === '1'",
            arg=str(record["id"]),
        )
        assert page.get_attribute("#canvas", "data-tool") == kind and near(placed(page), record["points"], 0.0)
        assert drawn(page) == record["draw_px"] and page.text_content("#saved").startswith(f"Saved measurement #{record['id']}")
        shown_equals_stored(page, record)
