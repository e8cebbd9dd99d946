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

SPEC = "sim:boxes?distance=1.2&seed=3&fps=5"
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
