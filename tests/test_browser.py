"""The product end to end: `depthruler serve` on the simulated poster, a real browser clicks the two
ends of the poster, and the distance the page shows must be within 2 % of the simulator's truth."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = "sim:poster?distance=2&lighting=indoor&contention=0.5&seed=7&fps=5"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    port = _free_port()
    db = tmp_path_factory.mktemp("serve") / "h.db"
    cmd = [sys.executable, "-m", "service.cli", "serve", "--source", SPEC, "--port", str(port), "--db", str(db)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                pytest.fail(f"depthruler serve exited: {proc.stdout.read().decode(errors='replace')}")
            try:
                if httpx.get(f"{base}/api/frames/latest", params={"wait": 2}, timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"no frame from {SPEC} within 60 s: {httpx.get(base + '/api/source').text}")
            time.sleep(0.3)
        yield base
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def page(browser):
    pg = browser.new_page(viewport={"width": 1440, "height": 900})
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.errors = errors  # type: ignore[attr-defined]
    yield pg
    pg.close()


def _click_image(page, frame: dict, px: list[float]) -> None:
    """Click image pixel ``px`` (pixel-centre convention) on the displayed, scaled canvas."""
    box = page.locator("#canvas").bounding_box()
    sx, sy = box["width"] / frame["width"], box["height"] / frame["height"]
    page.mouse.click(box["x"] + (px[0] + 0.5) * sx, box["y"] + (px[1] + 0.5) * sy)


def test_click_poster_ends_reads_true_length(server, page, tmp_path):
    page.goto(server + "/")
    page.wait_for_function("document.getElementById('canvas').dataset.frameId", timeout=30_000)
    page.keyboard.press("f")  # freeze from the keyboard
    page.wait_for_function("document.getElementById('frame-tag').textContent.startsWith('frozen')")
    fid = int(page.get_attribute("#canvas", "data-frame-id"))
    frame = httpx.get(f"{server}/api/frames/{fid}").json()
    truth = frame["truth"]
    assert truth and truth["target"].startswith("poster") and truth["length_m"] > 0.3

    _click_image(page, frame, truth["p1_px"])
    _click_image(page, frame, truth["p2_px"])
    page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
    shown = float(page.get_attribute("#distance", "data-metres"))
    text = page.text_content("#distance")
    print(f"page distance {shown:.4f} m, truth {truth['length_m']:.4f} m, error {100 * (shown / truth['length_m'] - 1):+.2f} %")
    assert shown == pytest.approx(truth["length_m"], rel=0.02)
    assert text == f"{shown:.3f} m"

    # the measurement is stored on that frame, with the clicked points
    stored = httpx.get(f"{server}/api/measurements").json()[0]
    assert stored["frame_id"] == fid and stored["distance_m"] == pytest.approx(shown)
    assert stored["p1"] == pytest.approx(truth["p1_px"], abs=1.0) and stored["p2"] == pytest.approx(truth["p2_px"], abs=1.0)
    assert page.locator("#history li").count() == 1

    page.wait_for_timeout(500)  # let the thumbnail and status settle for the picture
    # the README's picture is refreshed only on purpose: DEPTHRULER_SCREENSHOTS=docs
    shots = Path(os.environ.get("DEPTHRULER_SCREENSHOTS", "") or tmp_path)
    page.screenshot(path=str(shots / "screenshot.png"))

    # drag the second handle inwards: the segment is re-measured and replaces its history entry
    first_id = page.get_attribute("#distance", "data-id")
    box = page.locator("#canvas").bounding_box()
    s = box["width"] / frame["width"]
    x, y = box["x"] + (truth["p2_px"][0] + 0.5) * s, box["y"] + (truth["p2_px"][1] + 0.5) * s
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x - 100 * s, y, steps=5)
    page.mouse.up()
    page.wait_for_function(f"document.getElementById('distance').dataset.id !== '{first_id}'", timeout=30_000)
    shorter = float(page.get_attribute("#distance", "data-metres"))
    assert shorter == pytest.approx(shown * (1 - 100 / (truth["p2_px"][0] - truth["p1_px"][0])), rel=0.03)
    page.wait_for_function("document.querySelectorAll('#history li').length === 1")
    assert [m["id"] for m in httpx.get(f"{server}/api/measurements").json()] == [int(page.get_attribute("#distance", "data-id"))]
    shown = shorter

    page.keyboard.press("u")  # m -> cm: same metres, other text
    assert page.text_content("#distance") == f"{shown * 100:.1f} cm"
    page.keyboard.press("Escape")
    assert page.get_attribute("#distance", "data-metres") == ""
    assert page.errors == []  # type: ignore[attr-defined]


def test_touch_taps_measure(server, browser):
    """Touch input: the first tap freezes the shown frame, two taps measure (pointer events)."""
    truth = httpx.get(f"{server}/api/frames/latest").json()["truth"]  # the simulated scene is static
    ctx = browser.new_context(viewport={"width": 800, "height": 1000}, has_touch=True, is_mobile=True)
    page = ctx.new_page()
    page.goto(server + "/")
    page.wait_for_function("document.getElementById('canvas').dataset.frameId", timeout=30_000)
    box = page.locator("#canvas").bounding_box()
    s = box["width"] / 1280
    for p in (truth["p1_px"], truth["p2_px"]):
        page.touchscreen.tap(box["x"] + (p[0] + 0.5) * s, box["y"] + (p[1] + 0.5) * s)
        page.wait_for_timeout(300)
    page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
    shown = float(page.get_attribute("#distance", "data-metres"))
    assert page.text_content("#frame-tag").startswith("frozen")
    ctx.close()
    assert shown == pytest.approx(truth["length_m"], rel=0.02)
