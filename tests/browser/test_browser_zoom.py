"""Placing points finer than a finger: pinch zoom on a phone, the keyboard on a desktop, and a
read-depth mode that reads without measuring. `depthruler serve` on the simulated poster (a static
scene, so its truth end points are where the test places the handles)."""

from __future__ import annotations

import json

import httpx
import pytest

from browser_helpers import open_live, serve, watch

SPEC = "sim:poster?distance=2&lighting=indoor&contention=0.5&seed=7&fps=5"

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("zoom"), SPEC) as base:
        yield base


def open_live_frame(page, server) -> dict:
    """The page opened live, and the newest frame's JSON (its truth: where the handles go)."""
    open_live(page, server)
    return httpx.get(f"{server}/api/frames/latest").json()


def view_point(page, px) -> tuple[float, float]:
    """Viewport coordinates of image pixel ``px`` at the page's current zoom and pan (its canvas
    dataset), by the pixel-centre convention."""
    v = page.evaluate(
        "() => { const c = document.getElementById('canvas'); const r = c.getBoundingClientRect();"
        " return {l: r.left, t: r.top, w: r.width, h: r.height, cw: c.width, ch: c.height,"
        " k: +c.dataset.zoom || 1, x: +c.dataset.viewX || 0, y: +c.dataset.viewY || 0}; }"
    )
    return (v["l"] + (px[0] + 0.5 - v["x"]) * v["k"] * v["w"] / v["cw"],
            v["t"] + (px[1] + 0.5 - v["y"]) * v["k"] * v["h"] / v["ch"])  # fmt: skip


def touches(cdp, kind: str, *points) -> None:
    pts = [{"x": x, "y": y, "radiusX": 8, "radiusY": 8, "force": 1, "id": i} for i, (x, y) in enumerate(points)]
    cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": pts})


def pinch(page, cdp, centre, start_gap: float, end_gap: float) -> None:
    """Two fingers either side of ``centre``, spread from ``start_gap`` to ``end_gap`` px apart."""
    cx, cy = centre
    touches(cdp, "touchStart", (cx - start_gap / 2, cy))
    touches(cdp, "touchStart", (cx - start_gap / 2, cy), (cx + start_gap / 2, cy))
    for k in range(1, 9):
        g = start_gap + (end_gap - start_gap) * k / 8
        touches(cdp, "touchMove", (cx - g / 2, cy), (cx + g / 2, cy))
    touches(cdp, "touchEnd")
    page.wait_for_timeout(150)


def points(page) -> list[list[float]]:
    return json.loads(page.get_attribute("#canvas", "data-points") or "[]")


def history_count(server) -> int:
    return len(httpx.get(f"{server}/api/measurements?limit=1000").json())


def test_phone_4x_pinch_places_each_handle_within_half_a_pixel(server, browser):
    ctx = browser.new_context(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True, device_scale_factor=2)
    page = ctx.new_page()
    problems = watch(page)
    frame = open_live_frame(page, server)
    truth = frame["truth"]
    cdp = ctx.new_cdp_session(page)
    before = history_count(server)
    unzoomed = page.locator("#canvas").bounding_box()["width"] / frame["width"]  # CSS px per image px at 1x
    for i, target in enumerate((truth["p1_px"], truth["p2_px"])):
        if i:
            page.locator("#zoom-reset").tap()  # back to the whole image, to pinch in on the other end
            page.wait_for_function("document.getElementById('canvas').dataset.zoom === '1'")
        pinch(page, cdp, view_point(page, target), 40, 160)  # fingers 4x further apart: 4x zoom
        assert float(page.get_attribute("#canvas", "data-zoom")) == pytest.approx(4.0)
        assert page.get_attribute("#canvas", "data-frozen") == "1"  # zoom is on the frozen frame
        assert len(points(page)) == i  # the pinch's first finger placed nothing
        # the finger lands 6 px off and slides onto the end; the loupe shows the pixel under it
        x, y = view_point(page, target)
        touches(cdp, "touchStart", (x + 6, y + 5))
        touches(cdp, "touchMove", (x + 3, y + 2))
        touches(cdp, "touchMove", (x, y))
        page.wait_for_timeout(150)
        seen = page.evaluate("() => { const l = document.getElementById('loupe'); return [!l.classList.contains('hidden'), +l.dataset.x, +l.dataset.y]; }")
        touches(cdp, "touchEnd")
        assert seen == [True, round(target[0]), round(target[1])]
        placed = points(page)[i]
        # a touch position arrives in whole CSS px: at 4x that is a quarter of what it is at 1x
        assert abs(placed[0] - target[0]) <= 0.5 and abs(placed[1] - target[1]) <= 0.5, (placed, target)
        # the handle is drawn where the point is: its screen position is the finger's
        hx, hy = view_point(page, placed)
        assert abs(hx - x) <= 0.5 and abs(hy - y) <= 0.5
        page.wait_for_timeout(150)
    page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
    stored = httpx.get(f"{server}/api/measurements/{page.get_attribute('#distance', 'data-id')}").json()
    for p, target in zip((stored["p1"], stored["p2"]), (truth["p1_px"], truth["p2_px"])):
        assert abs(p[0] - target[0]) <= 0.5 and abs(p[1] - target[1]) <= 0.5, (p, target)
    assert stored["distance_m"] == pytest.approx(truth["length_m"], rel=0.02)
    # the finger's 3 screen px become a quarter as many image px at 4x: the uncertainty knows the zoom
    assert stored["options"]["click_px"] == pytest.approx(3.0 / (4 * unzoomed), abs=0.011)
    assert history_count(server) == before + 1
    ctx.close()
    assert problems == [], "\n".join(problems)


def test_read_depth_tap_stores_nothing(server, browser):
    ctx = browser.new_context(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True, device_scale_factor=2)
    page = ctx.new_page()
    problems = watch(page)
    frame = open_live_frame(page, server)
    cdp = ctx.new_cdp_session(page)
    before = history_count(server)
    box = page.locator("#read-depth").bounding_box()
    assert box["width"] >= 44 and box["height"] >= 44  # a finger's target
    page.locator("#read-depth").tap()
    assert page.get_attribute("#read-depth", "aria-pressed") == "true"
    t = frame["truth"]
    mid = [round((t["p1_px"][i] + t["p2_px"][i]) / 2) for i in (0, 1)]
    for px in ([round(v) for v in t["p1_px"]], mid, [round(v) for v in t["p2_px"]]):  # three taps on the poster: the old page measured with two
        x, y = view_point(page, px)
        touches(cdp, "touchStart", (x, y))
        touches(cdp, "touchEnd")
        page.wait_for_function("p => document.getElementById('readout').dataset.px === p", arg=f"{px[0]},{px[1]}")
        fid = page.get_attribute("#readout", "data-frame-id")
        api = httpx.get(f"{server}/api/frames/{fid}/depth", params={"x": px[0], "y": px[1]}).json()
        shown = page.get_attribute("#readout", "data-depth-m")
        assert api["depth_m"] is not None and float(shown) == pytest.approx(api["depth_m"], rel=1e-9)
        assert points(page) == []
    page.wait_for_timeout(500)
    assert history_count(server) == before
    assert page.get_attribute("#canvas", "data-frozen") == ""  # reading does not freeze the live view
    # read mode off: the same tap places a point again
    page.locator("#read-depth").tap()
    x, y = view_point(page, [200, 180])
    touches(cdp, "touchStart", (x, y))
    touches(cdp, "touchEnd")
    page.wait_for_function("document.getElementById('canvas').dataset.points !== '[]'")
    assert len(points(page)) == 1
    ctx.close()
    assert problems == [], "\n".join(problems)


def test_keyboard_only_measurement(server, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    problems = watch(page)
    frame = open_live_frame(page, server)
    truth = frame["truth"]
    before = history_count(server)
    for _ in range(40):  # Tab through the controls to the image
        page.keyboard.press("Tab")
        if page.evaluate("document.activeElement.id") == "canvas":
            break
    assert page.evaluate("document.activeElement.id") == "canvas"
    page.keyboard.press("Enter")  # two handles, on the frozen frame
    page.wait_for_function("JSON.parse(document.getElementById('canvas').dataset.points || '[]').length === 2")
    assert page.get_attribute("#canvas", "data-frozen") == "1"
    page.keyboard.press("+")  # zoom in on the active handle (1.5x); the keys still move whole image px
    assert float(page.get_attribute("#canvas", "data-zoom")) == pytest.approx(1.5)
    targets = [[round(v) for v in truth["p1_px"]], [round(v) for v in truth["p2_px"]]]
    for i, target in enumerate(targets):
        assert page.get_attribute("#canvas", "data-active") == str(i)
        start = points(page)[i]
        for axis, (minus, plus) in enumerate((("ArrowLeft", "ArrowRight"), ("ArrowUp", "ArrowDown"))):
            d = int(target[axis] - start[axis])
            key = plus if d > 0 else minus
            for _ in range(abs(d) // 10):
                page.keyboard.press(f"Shift+{key}")
            for _ in range(abs(d) % 10):
                page.keyboard.press(key)
        assert points(page)[i] == target
        if i == 0:
            page.keyboard.press("Tab")  # to the other handle
    assert history_count(server) == before  # nudging alone measures nothing
    page.keyboard.press("Enter")
    page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
    stored = httpx.get(f"{server}/api/measurements/{page.get_attribute('#distance', 'data-id')}").json()
    assert [stored["p1"], stored["p2"]] == targets
    assert stored["distance_m"] == pytest.approx(truth["length_m"], rel=0.02)
    assert float(page.get_attribute("#distance", "data-metres")) == stored["distance_m"]
    # a nudge after the answer, then Enter: re-measured, replacing the history entry
    page.keyboard.press("ArrowLeft")
    page.keyboard.press("Enter")
    page.wait_for_function("id => document.getElementById('distance').dataset.id !== id", arg=str(stored["id"]))
    again = httpx.get(f"{server}/api/measurements/{page.get_attribute('#distance', 'data-id')}").json()
    assert again["p2"] == [targets[1][0] - 1, targets[1][1]]
    page.wait_for_timeout(300)
    assert history_count(server) == before + 1
    page.keyboard.press("Escape")  # cancels the points
    assert points(page) == []
    page.keyboard.press("Tab")  # with no handles, Tab leaves the image
    assert page.evaluate("document.activeElement.id") != "canvas"
    page.close()
    assert problems == [], "\n".join(problems)


def test_wheel_zoom_keeps_the_point_under_the_cursor_and_space_drag_pans(server, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    problems = watch(page)
    frame = open_live_frame(page, server)
    target = frame["truth"]["p1_px"]
    x, y = (round(c) for c in view_point(page, target))  # mouse events arrive in whole CSS px
    box = page.locator("#canvas").bounding_box()
    under = [(x - box["x"]) * frame["width"] / box["width"] - 0.5, (y - box["y"]) * frame["height"] / box["height"] - 0.5]
    page.mouse.move(x, y)
    page.mouse.wheel(0, -300)  # three notches in: zoom on the frozen frame about the cursor
    page.wait_for_function("+document.getElementById('canvas').dataset.zoom > 1.9")
    # the page says frozen once the server holds the frame (a round trip after the wheel), and the
    # zoom stays where the wheel put it
    page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'", timeout=5_000)
    zx, zy = view_point(page, under)
    assert abs(zx - x) < 0.01 and abs(zy - y) < 0.01  # the image point under the cursor stayed there
    k = float(page.get_attribute("#canvas", "data-zoom"))
    vx0, vy0 = float(page.get_attribute("#canvas", "data-view-x")), float(page.get_attribute("#canvas", "data-view-y"))
    # space held: a drag pans by the distance dragged (in image px: CSS px x image px per CSS px)
    page.keyboard.down(" ")
    page.mouse.down()
    page.mouse.move(x - 60, y - 30, steps=6)
    page.mouse.up()
    page.keyboard.up(" ")
    per_css = frame["width"] / page.locator("#canvas").bounding_box()["width"] / k
    assert float(page.get_attribute("#canvas", "data-view-x")) == pytest.approx(vx0 + 60 * per_css, abs=1e-6)
    assert float(page.get_attribute("#canvas", "data-view-y")) == pytest.approx(vy0 + 30 * per_css, abs=1e-6)
    assert points(page) == []  # the pan placed nothing
    # a click at the zoomed, panned view lands on the pixel under it
    x, y = view_point(page, target)
    page.mouse.click(x, y)
    placed = points(page)[0]
    assert abs(placed[0] - target[0]) <= 0.5 and abs(placed[1] - target[1]) <= 0.5, (placed, target)
    page.close()
    assert problems == [], "\n".join(problems)
