"""The page's "Measure over N frames (hold still)" control in a real browser: the choice
reaches the API, the answer pools the frozen frame and the ones before it, and the page says how
many frames were used and how much narrower one sigma got."""

from __future__ import annotations

import re

import httpx
import pytest

from browser_helpers import image_point, open_live, serve, watch

SPEC = "sim:poster?distance=6&lighting=indoor&seed=5&fps=8"

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_measure_over_ten_frames_shows_frames_used_and_gain(tmp_path, browser):
    with serve(tmp_path, SPEC) as server:
        page = browser.new_context(viewport={"width": 1440, "height": 900}).new_page()
        watch(page)
        open_live(page, server)
        page.wait_for_function("Number(document.getElementById('canvas').dataset.frameId) >= 12", timeout=30_000)
        page.select_option("#frames", "10")
        page.keyboard.press("f")
        page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
        fid = int(page.get_attribute("#canvas", "data-frame-id"))
        frame = httpx.get(f"{server}/api/frames/{fid}").json()
        truth = frame["truth"]
        page.mouse.click(*image_point(page, frame, truth["p1_px"]))
        page.mouse.click(*image_point(page, frame, truth["p2_px"]))
        page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
        stored = httpx.get(f"{server}/api/measurements").json()[0]
        assert stored["frames_used"] == 10 and stored["frame_ids"] == list(range(fid - 9, fid + 1))
        text = page.text_content("#r-frames")
        m = re.fullmatch(r"10 of 10 used · 1σ (\d+\.\d\d)× narrower than one frame", text)
        assert m, text
        assert float(m[1]) == pytest.approx(stored["single_frame_uncertainty_m"] / stored["uncertainty_m"], abs=0.006)
        assert abs(stored["distance_m"] - truth["length_m"]) <= stored["interval_m"][1] - stored["distance_m"]
        assert page.problems == [], "\n".join(page.problems)  # type: ignore[attr-defined]
