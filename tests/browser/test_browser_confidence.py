"""The confidence view and the weak stretch in a real browser, on the simulator's textureless wall
beside a poster through SGBM (``sim:plain-wall?mode=stereo``): the third view shows
``confidence.png`` (black on the wall, white on the poster), a segment measured on the wall is drawn
with a dashed orange band over its weak stretch and the panel says why, one on the poster has none; a
source without confidence has the view disabled, saying so."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest

from browser_helpers import image_point, open_live, serve, watch
from device import open_source

SPEC = "sim:plain-wall?mode=stereo&width=640&height=360&distance=2.5&seed=3&fps=4"
WEAK_RGB = (255, 140, 26)  # app.js WEAK_COLOR

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def canvas_rgb(page, points) -> list[list[int]]:
    """The canvas's RGB at image pixels ``points`` (the canvas holds the image at its own size)."""
    return page.evaluate(
        """(pts) => { const c = document.getElementById('canvas').getContext('2d');
             return pts.map(([x, y]) => Array.from(c.getImageData(x, y, 1, 1).data.slice(0, 3))); }""",
        points,
    )


def band_pixels(p1, p2, t0: float, t1: float, off: int = 3) -> list[list[int]]:
    """Pixels ``off`` rows above and below a horizontal segment's part [t0, t1]: on the weak band,
    clear of the segment's line and of the sample dots."""
    y = int(round(p1[1]))
    xs = range(int(p1[0] + t0 * (p2[0] - p1[0])) + 2, int(p1[0] + t1 * (p2[0] - p1[0])) - 1)
    return [[x, y + d] for x in xs for d in (-off, off)]


def is_weak(rgb) -> bool:
    return all(abs(a - b) <= 8 for a, b in zip(rgb, WEAK_RGB))


def poster_px() -> tuple[list[float], list[float]]:
    """The poster's clicks, 10 % inside each of its edges (the truth is geometry, the same every frame)."""
    with open_source(f"{SPEC}&target=poster-width") as src:
        t = src.read(timeout_s=30).meta["truth"]
    a, b = np.asarray(t.p1_px, float), np.asarray(t.p2_px, float)
    return (a + 0.1 * (b - a)).tolist(), (b - 0.1 * (b - a)).tolist()


def test_confidence_view_and_the_weak_stretch_of_a_wall_segment(tmp_path, browser):
    with serve(tmp_path, SPEC) as server:
        page = browser.new_context(viewport={"width": 1440, "height": 900}).new_page()
        problems = watch(page)
        images: list[str] = []
        page.on("request", lambda r: images.append(r.url) if "/api/frames/" in r.url and r.url.endswith((".png", ".jpg")) else None)
        open_live(page, server)
        assert page.is_enabled("#view-confidence")
        page.keyboard.press("c")  # the view's key, as the footer lists it
        page.wait_for_function("document.getElementById('view-confidence').classList.contains('active')")
        assert page.get_attribute("#canvas", "data-view") == "confidence"
        assert "<kbd>c</kbd> confidence" in page.inner_html("footer.keys")
        page.keyboard.press("f")
        page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
        fid = int(page.get_attribute("#canvas", "data-frame-id"))
        page.wait_for_function("id => document.getElementById('canvas').dataset.frameId === String(id)", arg=fid)
        page.wait_for_function("u => document.getElementById('canvas').dataset.image === u", arg=f"api/frames/{fid}/confidence.png")
        assert any(u.endswith(f"/api/frames/{fid}/confidence.png") for u in images), images[-5:]  # asked of the server
        assert page.is_visible("#confidence-bar") and page.is_hidden("#colorbar")
        frame = httpx.get(f"{server}/api/frames/{fid}").json()
        wall = frame["truth"]["p1_px"], frame["truth"]["p2_px"]
        assert frame["truth"]["target"] == "wall-width"
        poster = poster_px()
        # on screen: the grey confidence, dark on the plain wall, bright on the poster
        y = int(wall[0][1])
        on_wall = canvas_rgb(page, [[int(x), y - 6] for x in np.linspace(wall[0][0], wall[1][0], 9)])
        on_poster = canvas_rgb(page, [[int(x), y - 6] for x in np.linspace(poster[0][0], poster[1][0], 9)])
        assert all(r == g == b for r, g, b in on_wall + on_poster)  # grey: the confidence, not the colour image
        print(f"view grey: wall {np.mean(on_wall):.0f}, poster {np.mean(on_poster):.0f}")
        assert np.mean(on_wall) < 100 and np.mean(on_poster) > 200

        # the wall segment: the band over its weak stretch, the reason and what to do in the panel
        page.mouse.click(*image_point(page, frame, wall[0]))
        page.mouse.click(*image_point(page, frame, wall[1]))
        page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
        mid = int(page.get_attribute("#distance", "data-id"))
        stored = httpx.get(f"{server}/api/measurements/{mid}").json()
        weak = stored["weak_stretches"]
        covered = sum(t1 - t0 for t0, t1 in weak)
        print(f"wall segment: weak {weak} ({covered:.0%}), reasons {stored['reasons']}")
        assert covered >= 0.9
        assert json.loads(page.get_attribute("#canvas", "data-weak")) == weak  # what the segment drew
        px = [p for t0, t1 in weak for p in band_pixels(*wall, t0, t1)]
        orange = sum(map(is_weak, canvas_rgb(page, px))) / len(px)
        print(f"orange share beside the weak stretch: {orange:.2f}")
        assert orange >= 0.4  # the band's dashes: 8 on, 5 off
        assert "low matcher confidence along the segment" in page.text_content("#reasons")
        assert "dashed orange stretch" in page.text_content("#advice")

        # a segment on the poster: no weak stretch, nothing orange beside it
        page.keyboard.press("Escape")
        page.mouse.click(*image_point(page, frame, poster[0]))
        page.mouse.click(*image_point(page, frame, poster[1]))
        page.wait_for_function("prev => { const d = document.getElementById('distance').dataset; return d.metres && d.id !== prev; }",
                               arg=str(mid), timeout=30_000)
        assert page.get_attribute("#canvas", "data-weak") == "[]"
        assert not any(map(is_weak, canvas_rgb(page, band_pixels(*poster, 0.0, 1.0))))
        page.keyboard.press("c")  # back to colour: the colour image again
        page.wait_for_function("document.getElementById('view-color').classList.contains('active')")
        page.wait_for_function("u => document.getElementById('canvas').dataset.image === u", arg=f"api/frames/{fid}/color.jpg")

        # live again, then the view switched and the frame frozen in one go (before the confidence image
        # can load): the frozen frame is shown in the view the buttons say, not left in colour
        page.keyboard.press("f")
        page.wait_for_function("document.getElementById('canvas').dataset.frozen === ''")
        page.evaluate("() => { for (const key of ['c', 'f']) document.dispatchEvent(new KeyboardEvent('keydown', {key, bubbles: true})); }")
        page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
        again = int(page.get_attribute("#canvas", "data-frame-id"))
        page.wait_for_function("u => document.getElementById('canvas').dataset.image === u", arg=f"api/frames/{again}/confidence.png",
                               timeout=15_000)
        assert problems == [], "\n".join(problems)


def test_a_source_without_confidence_disables_the_view(tmp_path, browser):
    with serve(tmp_path, "sim:boxes?confidence=false&width=320&height=180&fps=4") as server:
        page = browser.new_context(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True).new_page()
        problems = watch(page)
        open_live(page, server)
        page.wait_for_function("document.getElementById('view-confidence').disabled")
        assert "gives no confidence" in page.get_attribute("#view-confidence", "title")
        box = page.locator("#view-confidence").bounding_box()
        assert box["width"] >= 44 and box["height"] >= 44 and box["x"] + box["width"] <= 390  # a finger's target, on screen
        page.keyboard.press("c")  # the key does nothing either: no 404 asked for
        page.wait_for_timeout(300)
        assert page.get_attribute("#canvas", "data-view") in (None, "color")
        assert problems == [], "\n".join(problems)
