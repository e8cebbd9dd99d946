"""A replay in the browser: the page says it is a replay, names it, shows the frame number, and
pause, step, step back and scrub drive it. The recording is made from the simulator with the
project's recorder (`depthruler record`) in a temporary folder."""

from __future__ import annotations

import subprocess
import sys

import httpx
import pytest

from browser_helpers import ROOT, open_live, serve, watch

pytestmark = [pytest.mark.browser, pytest.mark.slow]

FRAMES = 6


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    folder = tmp_path_factory.mktemp("replay")
    rec = folder / "shelf-take-1"
    cmd = [sys.executable, "-m", "cli.main", "record", "--source", "sim:poster?distance=2&fps=0&width=640&height=360",
           "--out", str(rec), "--frames", str(FRAMES)]  # fmt: skip
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, timeout=120)
    with serve(folder, f"replay:{rec}?loop=1&realtime=1") as base:
        yield base


def test_replay_badge_and_frame_stepping(server, browser):
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    problems = watch(page)
    open_live(page, server)
    page.wait_for_function("document.getElementById('source-badge').dataset.kind === 'replay'")
    assert page.text_content("#source-badge") == "REPLAY shelf-take-1"
    assert page.locator("#replay-bar").is_visible()

    def index() -> int:
        return int(page.get_attribute("#replay-pos", "data-index"))

    def shown_index() -> int:  # the replay index of the frame on screen, from the server
        fid = page.get_attribute("#canvas", "data-frame-id")
        return httpx.get(f"{server}/api/frames/{fid}").json()["replay_index"]

    page.click("#replay-play")  # pause
    page.wait_for_function("document.getElementById('replay-bar').dataset.paused === '1'")
    # the last frame delivered (a read already under way when the pause came may still land)
    paused_at = None
    while (now := httpx.get(f"{server}/api/source").json()["replay"]["index"]) != paused_at:
        paused_at = now
        page.wait_for_timeout(400)
    page.wait_for_function("n => document.getElementById('frame-tag').dataset.index === String(n)", arg=paused_at)
    assert shown_index() == paused_at and index() == paused_at
    # 1-based on screen, the same in the bar and on the image: the last frame reads "frame 6 of 6"
    assert page.text_content("#replay-pos") == f"frame {paused_at + 1} of {FRAMES}"
    assert f"frame {paused_at + 1} of {FRAMES}" in page.text_content("#frame-tag")
    page.wait_for_timeout(500)
    assert shown_index() == paused_at  # paused: the stream stands still

    page.click("#replay-step")
    page.wait_for_function("n => +document.getElementById('replay-pos').dataset.index === n", arg=(paused_at + 1) % FRAMES)
    page.wait_for_function("n => document.getElementById('frame-tag').dataset.index === String(n)", arg=(paused_at + 1) % FRAMES)
    assert shown_index() == (paused_at + 1) % FRAMES

    page.keyboard.press(",")  # one frame back
    page.wait_for_function("n => +document.getElementById('replay-pos').dataset.index === n", arg=paused_at)
    page.wait_for_function("n => document.getElementById('frame-tag').dataset.index === String(n)", arg=paused_at)

    page.locator("#replay-scrub").fill(str(FRAMES - 1))  # scrub to the last frame
    page.wait_for_function("n => document.getElementById('frame-tag').dataset.index === String(n)", arg=FRAMES - 1)
    assert index() == FRAMES - 1 == shown_index()

    # a measurement on the replay keeps the frame's index in the recording (for `export --measurements`)
    page.click("#freeze")
    page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
    box = page.locator("#canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.35, box["y"] + box["height"] * 0.5)
    page.mouse.click(box["x"] + box["width"] * 0.6, box["y"] + box["height"] * 0.5)
    page.wait_for_function("document.getElementById('distance').dataset.metres")
    mid = page.get_attribute("#distance", "data-id")
    stored = httpx.get(f"{server}/api/measurements/{mid}").json()
    assert stored["frame_index"] == FRAMES - 1
    # named after the replay and its recording, not after the simulator it was recorded from
    assert (stored["source_kind"], stored["recording"], stored["recorded_source"]) == ("replay", "shelf-take-1", "sim")
    assert stored["source"].startswith("replay:") and stored["source"].split("?")[0].endswith("shelf-take-1")
    assert page.text_content("#replay-pos") == f"frame {FRAMES} of {FRAMES}"

    page.click("#replay-play")  # play again: goes live, the replay moves on
    page.wait_for_function("document.getElementById('replay-bar').dataset.paused === ''")
    page.wait_for_function("n => document.getElementById('frame-tag').dataset.index !== String(n)", arg=FRAMES - 1)
    assert problems == [], "\n".join(problems)
