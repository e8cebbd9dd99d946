"""The page's small frictions, in a real browser: where a recording went (a toast with its folder
and a way to play it back), a depth colour bar with a few round ticks, and finger-sized targets on a
phone. `depthruler serve` on the simulated poster with its recordings in a temporary folder."""

from __future__ import annotations

import re
from pathlib import Path

import httpx
import pytest

from browser_helpers import open_live, serve, watch

SPEC = "sim:poster?distance=2&lighting=indoor&contention=0.5&seed=7&fps=5"

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    folder = tmp_path_factory.mktemp("page")
    with serve(folder, SPEC, "--recordings", str(folder / "recordings")) as base:
        yield base, folder / "recordings"


def small_targets(page) -> list[str]:
    """Visible controls smaller than 44 x 44 CSS px."""
    return page.evaluate(
        """() => [...document.querySelectorAll('button, a, select, input')].filter((el) => {
            const r = el.getBoundingClientRect(); const cs = getComputedStyle(el);
            return r.width > 0 && r.height > 0 && cs.visibility !== 'hidden';
          }).map((el) => { const r = el.getBoundingClientRect(); return [el.id || el.className || el.tagName, r.width, r.height]; })
          .filter(([, w, h]) => w < 44 || h < 44).map(([n, w, h]) => `${n} ${w.toFixed(0)}x${h.toFixed(0)}`)"""
    )


def test_recording_toast_opens_the_replay_and_phone_targets_are_44px(server, browser):
    base, recordings = server
    ctx = browser.new_context(viewport={"width": 390, "height": 844}, has_touch=True, is_mobile=True, device_scale_factor=2)
    page = ctx.new_page()
    problems = watch(page)
    open_live(page, base)
    page.locator("#record").tap()
    page.wait_for_function("document.getElementById('record').classList.contains('on')")
    page.wait_for_function("+(document.getElementById('record-label').textContent.match(/\\d+/) || [0])[0] >= 3", timeout=30_000)
    page.locator("#record").tap()  # stop: the toast says where the recording went
    page.wait_for_function("!document.getElementById('toast').classList.contains('hidden')")
    path = Path(page.text_content("#toast-path"))
    assert path.parent == recordings.resolve() and (path / "manifest.json").is_file()
    frames = len((path / "frames.jsonl").read_text().splitlines())
    assert page.text_content("#toast-text") == f"Recorded {frames} frames to"
    # every control on the phone, the toast's and the CSV / JSON links included, is a finger's size
    assert small_targets(page) == []
    for sel in ("#csv", "#json", "#toast-open"):
        box = page.locator(sel).bounding_box()
        assert box["width"] >= 44 and box["height"] >= 44, sel

    page.locator("#toast-open").tap()  # play it back here
    # the badge says REPLAY from the spec at once, and the recording's name once the replay is open
    page.wait_for_function("t => document.getElementById('source-badge').textContent === t", arg=f"REPLAY {path.name}", timeout=30_000)
    assert page.get_attribute("#source-badge", "data-kind") == "replay"
    assert page.locator("#toast").is_hidden()
    status = httpx.get(f"{base}/api/source").json()
    assert status["replay"]["recording"] == path.name and status["replay"]["frames"] == frames and status["home"] == SPEC
    page.wait_for_function("document.getElementById('frame-tag').dataset.index !== ''", timeout=30_000)
    assert re.search(rf"frame \d+ of {frames}", page.text_content("#replay-pos"))
    assert small_targets(page) == []  # the replay bar's controls too
    page.locator("#replay-home").tap()  # and back to the live simulator
    page.wait_for_function("document.getElementById('source-badge').dataset.kind === 'sim'", timeout=30_000)
    assert httpx.get(f"{base}/api/source").json()["home"] == ""
    assert page.locator("#replay-bar").is_hidden()
    # a folder that is no recording is refused with a message, not played
    bad = httpx.post(f"{base}/api/source", json={"recording": "nope"}, headers={"Origin": base})
    assert bad.status_code == 404 and "no manifest.json" in bad.json()["detail"]
    assert httpx.post(f"{base}/api/source", json={"recording": "../x"}, headers={"Origin": base}).status_code == 422
    ctx.close()
    assert problems == [], "\n".join(problems)


def test_colour_bar_has_four_to_six_round_ticks_in_place(server, browser):
    base, _ = server
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    problems = watch(page)
    open_live(page, base)
    page.keyboard.press("f")
    page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
    fid = page.get_attribute("#canvas", "data-frame-id")
    scale = httpx.get(f"{base}/api/frames/{fid}/depth-scale").json()
    page.keyboard.press("d")  # the depth view
    for units, factor in (("m", 1.0), ("cm", 100.0)):
        page.select_option("#units", units)
        page.wait_for_function("document.querySelectorAll('#colorbar-ticks span').length > 0")
        ticks = page.locator("#colorbar-ticks span")
        labels = ticks.all_text_contents()
        assert 4 <= len(labels) <= 6, labels
        lo, hi = scale["disparity_px"]
        xs = []
        for i, label in enumerate(labels):
            m = re.fullmatch(rf"(\d+(?:\.\d+)?) {units}", label)
            assert m, label
            value = float(m[1])
            digits = m[1].replace(".", "").strip("0")
            assert len(digits) <= 2, label  # round: 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 times a power of ten
            z = value / factor
            # placed where that depth's colour is: the bar runs linearly in disparity
            x = (scale["fx_baseline"] / z - scale["doffs"] - lo) / (hi - lo) * 100
            assert float(ticks.nth(i).get_attribute("data-x")) == pytest.approx(x, abs=0.01)
            xs.append(x)
        assert all(0 <= x <= 100 for x in xs) and all(b - a >= 8 for a, b in zip(xs, xs[1:])), xs  # apart, in order
        boxes = [ticks.nth(i).bounding_box() for i in range(len(labels))]
        assert all(a["x"] + a["width"] <= b["x"] for a, b in zip(boxes, boxes[1:]))  # no label covers another
    page.close()
    assert problems == [], "\n".join(problems)
