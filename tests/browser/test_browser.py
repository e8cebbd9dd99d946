"""The product end to end in a real browser: `depthruler serve` on the simulated poster, Debian's
chromium clicks, hovers, drags and taps like a person, and what the page shows is checked against the
API and the simulator's truth. One server for the module; no console errors anywhere.

Screenshots for the README go to a temporary folder, or to DEPTHRULER_SCREENSHOTS when it names one
(refresh docs/ on purpose: ``DEPTHRULER_SCREENSHOTS=docs pytest tests/browser/test_browser.py``)."""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from browser_helpers import image_point, open_live, serve, watch
from history.export import CSV_COLUMNS

SPEC = "sim:poster?distance=2&lighting=indoor&contention=0.5&seed=7&fps=5"

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve(tmp_path_factory.mktemp("serve"), SPEC) as base:
        yield base


@pytest.fixture
def page(browser):
    ctx = browser.new_context(viewport={"width": 1440, "height": 900}, accept_downloads=True)
    pg = ctx.new_page()
    watch(pg)
    yield pg
    ctx.close()
    assert pg.problems == [], "\n".join(pg.problems)  # type: ignore[attr-defined]


def shots_dir(tmp_path) -> Path:
    return Path(os.environ.get("DEPTHRULER_SCREENSHOTS", "") or tmp_path)


def freeze(page) -> dict:
    page.keyboard.press("f")
    page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
    return {"id": int(page.get_attribute("#canvas", "data-frame-id"))}


def wait_result(page, previous: str | None = None) -> float:
    page.wait_for_function(
        "prev => { const d = document.getElementById('distance').dataset; return d.metres && d.id !== prev; }",
        arg=previous or "",
        timeout=30_000,
    )
    return float(page.get_attribute("#distance", "data-metres"))


def test_click_poster_ends_reads_true_length(server, page, tmp_path):
    open_live(page, server)
    fid = freeze(page)["id"]
    frame = httpx.get(f"{server}/api/frames/{fid}").json()
    assert frame["frozen"]
    truth = frame["truth"]
    assert truth and truth["target"].startswith("poster") and truth["length_m"] > 0.3

    page.mouse.click(*image_point(page, frame, truth["p1_px"]))
    page.mouse.click(*image_point(page, frame, truth["p2_px"]))
    shown = wait_result(page)
    text = page.text_content("#distance")
    print(f"page distance {shown:.4f} m, truth {truth['length_m']:.4f} m, error {100 * (shown / truth['length_m'] - 1):+.2f} %")
    assert shown == pytest.approx(truth["length_m"], rel=0.02)
    assert text == f"{shown:.3f} m"

    # the measurement is stored on that frame, with the clicked points
    stored = httpx.get(f"{server}/api/measurements").json()[0]
    assert stored["frame_id"] == fid and stored["distance_m"] == pytest.approx(shown)
    assert stored["p1"] == pytest.approx(truth["p1_px"], abs=1.0) and stored["p2"] == pytest.approx(truth["p2_px"], abs=1.0)
    # a mouse's click error, 1.5 screen px, reaches the uncertainty in image pixels (MeasureOptions.click_px)
    scale = frame["width"] / page.locator("#canvas").bounding_box()["width"]
    assert stored["options"]["click_px"] == pytest.approx(1.5 * scale, abs=0.011)
    page.wait_for_function("document.querySelectorAll('#history li').length === 1")

    # the interval reads as "0.835 m ± 2 mm" and spans the 95 % interval the page was given
    interval = page.text_content("#interval")
    lo, hi = float(page.get_attribute("#interval", "data-low")), float(page.get_attribute("#interval", "data-high"))
    assert lo < shown < hi
    m = re.match(rf"{shown:.3f} m ± (\d+(?:\.(\d+))?) (mm|cm) · 95 %", interval)
    assert m, interval
    half = (hi - lo) / 2 * {"mm": 1000, "cm": 100}[m[3]]
    assert abs(float(m[1]) - half) <= 0.5 * 10 ** -len(m[2] or "") + 1e-9  # the half-width, rounded as written
    # each end: its depth, and whether it was measured there; the poster's ends are on the poster
    ends = page.locator("#ends .end")
    assert ends.count() == 2
    for i, p in enumerate((stored["p1_m"], stored["p2_m"])):
        assert ends.nth(i).text_content().startswith(f"P{i + 1} depth {p[2]:.3f} m")
        assert ends.nth(i).get_attribute("data-state") in ("measured", "extrapolated")

    page.wait_for_timeout(500)  # let the thumbnail and status settle for the picture
    page.screenshot(path=str(shots_dir(tmp_path) / "screenshot.png"))

    # drag the second handle inwards: the segment is re-measured and replaces its history entry
    first_id = page.get_attribute("#distance", "data-id")
    x, y = image_point(page, frame, truth["p2_px"])
    s = page.locator("#canvas").bounding_box()["width"] / frame["width"]
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x - 50 * s, y, steps=3)
    assert page.locator("#loupe").is_visible()  # magnified view while dragging
    page.mouse.move(x - 100 * s, y, steps=3)
    page.mouse.up()
    assert page.locator("#loupe").is_hidden()
    shorter = wait_result(page, first_id)
    assert shorter == pytest.approx(shown * (1 - 100 / (truth["p2_px"][0] - truth["p1_px"][0])), rel=0.03)
    page.wait_for_function("document.querySelectorAll('#history li').length === 1")
    assert [m["id"] for m in httpx.get(f"{server}/api/measurements").json()] == [int(page.get_attribute("#distance", "data-id"))]

    page.keyboard.press("u")  # m -> cm: same metres, other text
    assert page.text_content("#distance") == f"{shorter * 100:.1f} cm"
    page.keyboard.press("Escape")
    assert page.get_attribute("#distance", "data-metres") == ""
    page.keyboard.press("u"), page.keyboard.press("u"), page.keyboard.press("u")  # back to m for the next tests


def test_hover_depth_is_the_api_depth_and_colour_bar_in_metres(server, page):
    open_live(page, server)
    fid = freeze(page)["id"]
    frame = httpx.get(f"{server}/api/frames/{fid}").json()
    for px in ([300, 200], [640, 360], [1000, 150], [37, 690]):
        page.mouse.move(*image_point(page, frame, px))
        page.wait_for_function("px => document.getElementById('readout').dataset.px === px", arg=f"{px[0]},{px[1]}")
        api = httpx.get(f"{server}/api/frames/{fid}/depth", params={"x": px[0], "y": px[1]}).json()
        shown = page.get_attribute("#readout", "data-depth-m")
        assert page.get_attribute("#readout", "data-frame-id") == str(fid)
        if api["depth_m"] is None:
            assert shown == "" and "no data" in page.text_content("#readout")
        else:
            assert float(shown) == api["depth_m"]
            assert page.text_content("#readout") == f"depth {api['depth_m']:.3f} m · px ({px[0]}, {px[1]})"
    # the poster centre is 2 m away in the simulator
    page.mouse.move(*image_point(page, frame, [640, 200]))
    page.wait_for_function("document.getElementById('readout').dataset.px === '640,200'")
    assert float(page.get_attribute("#readout", "data-depth-m")) == pytest.approx(2.0, rel=0.03)

    page.keyboard.press("d")
    page.wait_for_function("!document.getElementById('colorbar').classList.contains('hidden') && document.getElementById('colorbar').dataset.near")
    scale = httpx.get(f"{server}/api/frames/{fid}/depth-scale").json()
    assert float(page.get_attribute("#colorbar", "data-near")) == pytest.approx(scale["depth_m"][0])
    assert float(page.get_attribute("#colorbar", "data-far")) == pytest.approx(scale["depth_m"][1])
    ticks = page.locator("#colorbar-ticks span").all_text_contents()
    assert len(ticks) >= 2 and all(t.endswith(" m") for t in ticks)
    assert page.text_content("#colorbar-range") == f"{scale['depth_m'][0]:.3f} m – {scale['depth_m'][1]:.3f} m"
    page.keyboard.press("d")


def test_annotated_png_csv_and_history_edits(server, page, tmp_path):
    open_live(page, server)
    fid = freeze(page)["id"]
    frame = httpx.get(f"{server}/api/frames/{fid}").json()
    truth = frame["truth"]
    page.mouse.click(*image_point(page, frame, truth["p1_px"]))
    page.mouse.click(*image_point(page, frame, truth["p2_px"]))
    shown = wait_result(page)
    mid = int(page.get_attribute("#distance", "data-id"))

    with page.expect_download() as dl:
        page.click("#save-png")
    path = tmp_path / "annotated.png"
    dl.value.save_as(path)
    annotated = cv2.imread(str(path), cv2.IMREAD_COLOR)
    raw = cv2.imdecode(np.frombuffer(httpx.get(f"{server}/api/frames/{fid}/color.png").content, np.uint8), cv2.IMREAD_COLOR)
    assert annotated.shape == raw.shape == (frame["height"], frame["width"], 3)
    assert np.array_equal(annotated[5:40, 5:40], raw[5:40, 5:40])  # the frame itself, untouched away from the drawing
    mid_px = [round((a + b) / 2) for a, b in zip(truth["p1_px"], truth["p2_px"])]
    assert np.abs(annotated[mid_px[1], mid_px[0]].astype(int) - raw[mid_px[1], mid_px[0]]).sum() > 60  # the segment

    # name and note it
    item = page.locator(f"#history li[data-id='{mid}']")
    item.locator(".h-edit").click()
    page.fill("#history form input[name=name]", "poster width")
    page.fill("#history form textarea[name=note]", "wall, 2 m")
    page.click("#history form button[type=submit]")
    page.wait_for_function(f"document.querySelector(\"#history li[data-id='{mid}'] .h-name\")?.textContent === 'poster width'")
    assert httpx.get(f"{server}/api/measurements/{mid}").json()["note"] == "wall, 2 m"

    # CSV in the page's units: mm
    page.select_option("#units", "mm")
    with page.expect_download() as dl:
        page.click("#csv")
    rows = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
    assert tuple(rows[0].keys()) == CSV_COLUMNS
    row = next(r for r in rows if int(r["id"]) == mid)
    assert row["units"] == "mm" and row["name"] == "poster width"
    assert float(row["distance"]) == pytest.approx(shown * 1000, abs=0.5)
    assert float(row["p1_Z"]) == pytest.approx(2000, rel=0.03) and row["frame_url"].endswith(f"/api/measurements/{mid}/color.png")
    assert httpx.get(row["frame_url"]).status_code == 200
    page.select_option("#units", "m")

    # reopen it from the history after going live: its saved frame comes back, frozen, with its segment
    page.click("#clear")
    page.keyboard.press("Escape")
    page.wait_for_function("document.getElementById('frame-tag').textContent.startsWith('live')")
    page.locator(f"#history li[data-id='{mid}'] .h-dist").click()
    page.wait_for_function(f"document.getElementById('distance').dataset.id === '{mid}' && document.getElementById('canvas').dataset.frozen === '1'")
    reopened = httpx.get(f"{server}/api/frames/{page.get_attribute('#canvas', 'data-frame-id')}").json()
    assert reopened["frozen"] and reopened["uid"] == httpx.get(f"{server}/api/measurements/{mid}").json()["frame_uid"]
    assert float(page.get_attribute("#distance", "data-metres")) == shown

    # the source filter lists the sources; delete with undo
    assert "sim" in page.locator("#history-filter option").all_text_contents()
    n = page.locator("#history li").count()
    item.locator(".h-del").click()
    assert page.locator(f"#history li[data-id='{mid}']").count() == 0 and page.locator("#undo").is_visible()
    page.click("#undo-btn")
    page.wait_for_selector(f"#history li[data-id='{mid}']")
    assert page.locator("#history li").count() == n and httpx.get(f"{server}/api/measurements/{mid}").status_code == 200
    item.locator(".h-del").click()
    page.evaluate("commitPendingDelete()")  # what the undo timer (or leaving the page) does
    page.wait_for_function(f"!document.querySelector(\"#history li[data-id='{mid}']\")")
    assert httpx.get(f"{server}/api/measurements/{mid}").status_code == 404
    page.wait_for_timeout(300)


def touch(cdp, kind: str, x: float, y: float) -> None:
    points = [] if kind == "touchEnd" else [{"x": x, "y": y, "radiusX": 8, "radiusY": 8, "force": 1, "id": 1}]
    cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": points})


def touch_place(page, cdp, start, end) -> dict:
    """Press at ``start``, slide to ``end`` (viewport px), lift; returns the loupe's state mid-way."""
    touch(cdp, "touchStart", *start)
    for k in range(1, 5):
        touch(cdp, "touchMove", start[0] + (end[0] - start[0]) * k / 4, start[1] + (end[1] - start[1]) * k / 4)
    page.wait_for_timeout(150)
    seen = page.evaluate(
        "() => { const l = document.getElementById('loupe'); const r = l.getBoundingClientRect();"
        " return {visible: !l.classList.contains('hidden'), x: +l.dataset.x, y: +l.dataset.y, bottom: r.bottom, top: r.top}; }"
    )
    touch(cdp, "touchEnd", *end)
    return seen


@pytest.mark.parametrize("width, height", [(390, 844), (360, 740)])
def test_phone_layout_and_touch_measurement_with_loupe(server, browser, tmp_path, width, height):
    ctx = browser.new_context(viewport={"width": width, "height": height}, has_touch=True, is_mobile=True, device_scale_factor=2)
    page = ctx.new_page()
    problems = watch(page)
    open_live(page, server)
    assert page.evaluate("document.documentElement.scrollWidth") <= width
    assert page.locator("footer.keys").is_hidden()  # no keyboard shortcuts on a touch screen
    for sel in ("#freeze", "#record", "#units", "#method", "#clear", "#view-disparity", "#source-badge"):
        box = page.locator(sel).bounding_box()
        assert box and box["x"] >= 0 and box["x"] + box["width"] <= width, sel
    truth = httpx.get(f"{server}/api/frames/latest").json()  # the simulated scene is static
    cdp = ctx.new_cdp_session(page)
    ends = [truth["truth"]["p1_px"], truth["truth"]["p2_px"]]
    for p in ends:
        # the finger lands 6 px off and slides onto the end while the loupe shows the pixel under it
        x, y = image_point(page, truth, p)
        seen = touch_place(page, cdp, (x + 6, y + 5), (x, y))
        assert seen["visible"] and abs(seen["x"] - p[0]) <= 2 and abs(seen["y"] - p[1]) <= 2
        assert seen["bottom"] <= y - 20 or seen["top"] >= y + 20  # the loupe is not under the finger
        page.wait_for_timeout(200)
    shown = wait_result(page)
    assert page.locator("#loupe").is_hidden()
    assert page.text_content("#frame-tag").startswith("frozen")
    assert shown == pytest.approx(truth["truth"]["length_m"], rel=0.02)
    # the number, its interval and the verdict area are on screen without scrolling
    assert page.evaluate("window.scrollY") == 0
    assert page.locator("#interval").bounding_box()["y"] + 20 <= height
    assert page.evaluate("document.documentElement.scrollWidth") <= width
    if width == 390:
        page.screenshot(path=str(shots_dir(tmp_path) / "screenshot-phone.png"))

    # grabbing a handle a little off keeps that offset: the handle moves with the finger, not under it
    mid = page.get_attribute("#distance", "data-id")
    before = httpx.get(f"{server}/api/measurements/{mid}").json()["p2"]
    s = page.locator("#canvas").bounding_box()["width"] / truth["width"]
    # a finger's tap, 3 screen px one sigma, is stated as the clicks' error in image pixels
    assert httpx.get(f"{server}/api/measurements/{mid}").json()["options"]["click_px"] == pytest.approx(min(50.0, 3.0 / s), abs=0.011)
    x, y = image_point(page, truth, before)
    touch_place(page, cdp, (x, y + 12), (x - 20, y + 12))
    wait_result(page, mid)
    after = httpx.get(f"{server}/api/measurements/{page.get_attribute('#distance', 'data-id')}").json()["p2"]
    px = 1 / s  # image pixels per CSS pixel: touch positions arrive in whole CSS pixels
    assert after[0] == pytest.approx(before[0] - 20 * px, abs=px) and after[1] == pytest.approx(before[1], abs=px)
    ctx.close()
    assert problems == [], "\n".join(problems)


def test_verdict_reasons_and_interval_render(server, page):
    """The core's verdict fields (quality, reasons, interval_m) on a stored measurement: shown with
    the number, with what to do when not "good"; without them the page still shows the interval."""
    open_live(page, server)
    fid = freeze(page)["id"]
    r = httpx.post(f"{server}/api/measure", json={"frame_id": fid, "p1": [215, 180], "p2": [424, 180]}, headers={"Content-Type": "application/json"})
    record = r.json()
    plain = {k: v for k, v in record.items() if k not in ("quality", "reasons", "interval_m")}
    page.evaluate("r => { state.points = [r.p1, r.p2]; state.result = r; showResult(r); draw(); }", plain)
    assert page.locator("#verdict").is_hidden() and page.locator("#why").is_hidden()
    assert " ± " in page.text_content("#interval") and "±1.96σ" in page.text_content("#interval")

    d = record["distance_m"]
    check = {**plain, "quality": "check", "interval_m": [d - 0.0021, d + 0.0019],
             "reasons": ["end point extrapolated", "few valid samples", "uncertainty above 24 %"]}  # the core's phrases
    page.evaluate("r => { state.result = r; showResult(r); draw(); }", check)
    assert page.text_content("#verdict") == "⚠ check" and page.locator("#verdict").is_visible()
    assert page.text_content("#interval") == f"{d:.3f} m ± 2 mm · 95 % interval"
    assert page.locator("#reasons li").all_text_contents() == check["reasons"]
    advice = page.locator("#advice li").all_text_contents()
    assert len(advice) == 3 and "inside the object's edges" in advice[0] and all("Move closer" in a for a in advice[1:])

    good = {**check, "quality": "good", "reasons": []}
    page.evaluate("r => { state.result = r; showResult(r); draw(); }", good)
    assert page.text_content("#verdict") == "✓ good" and page.locator("#why").is_hidden()
    noted = {**check, "quality": "good", "reasons": ["end point on a depth edge"]}  # informational: shown, no advice
    page.evaluate("r => { state.result = r; showResult(r); draw(); }", noted)
    assert page.locator("#reasons li").all_text_contents() == ["end point on a depth edge"]
    assert page.locator("#advice li").count() == 0 and page.locator("#why").is_visible()
    lopsided = {**check, "quality": "unreliable", "interval_m": [d - 0.05, d + 0.2]}
    page.evaluate("r => { state.result = r; showResult(r); draw(); }", lopsided)
    assert page.text_content("#interval").startswith(f"{d:.3f} m ({d - 0.05:.3f} – {d + 0.2:.3f} m)")
    assert page.text_content("#verdict") == "✕ unreliable"
