"""The accuracy check from the page: `depthruler serve` on the simulator's ChArUco board, Debian's chromium presses
"Check accuracy", and the page shows the check's picture, figures and findings as the API stored them, and its history."""

from __future__ import annotations

import httpx
import pytest

from browser_helpers import open_live, serve, watch

SPEC = "sim:charuco?distance=1.2&width=640&height=360&fps=5"
JSON = {"Content-Type": "application/json"}

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_the_check_button_shows_picture_findings_and_history(tmp_path, browser):
    with serve(tmp_path, SPEC) as base:
        # The stream's first frame has none before it: a 3-frame check on it checks that one and says so.
        assert httpx.post(f"{base}/api/frames/1/freeze", headers=JSON).status_code == 200
        first = httpx.post(f"{base}/api/checks", json={"frame_id": 1, "frames": 3}, timeout=120).json()
        assert first["frame_ids"] == [1] and first["frames_requested"] == 3 and first["frames_note"].startswith("used 1 of 3 frames")
        ctx = browser.new_context(viewport={"width": 1440, "height": 1000})
        page = ctx.new_page()
        problems = watch(page)
        open_live(page, base)
        assert page.locator("#check-history li").count() == 1 and "1 of 3 frames" in page.text_content("#check-history li")
        # the 3-frame check below is made on the frame this first click freezes: two frames must have come before it
        page.wait_for_function("Number(document.getElementById('canvas').dataset.frameId) >= 3", timeout=30_000)
        page.click("#check-run")  # freezes the frame on screen, then checks it
        page.wait_for_function(f"document.getElementById('check-card').dataset.checkId !== '{first['id']}'"
                               " && document.getElementById('check-card').dataset.checkId", timeout=60_000)
        assert page.get_attribute("#canvas", "data-frozen") == "1"
        frame_id = int(page.get_attribute("#canvas", "data-frame-id"))
        stored = httpx.get(f"{base}/api/checks").json()["checks"]
        assert len(stored) == 2
        rec = stored[0]
        assert page.get_attribute("#check-card", "data-check-id") == rec["id"] and rec["frame_id"] == frame_id
        assert int(page.get_attribute("#check-figures", "data-pairs")) == rec["figures"]["pairs"] >= 20
        assert float(page.get_attribute("#check-figures", "data-bias")) == pytest.approx(rec["figures"]["bias_pct"])
        assert page.locator("#check-findings li").count() == max(1, len(rec["findings"]))
        page.wait_for_function("document.getElementById('check-img').naturalWidth > 0", timeout=15_000)
        assert page.evaluate("document.getElementById('check-img').naturalWidth") > 300  # the picture, decoded
        status_word = {"ok": "good", "check": "check", "poor": "poor"}[rec["status"]]
        assert page.text_content("#check-status") == status_word
        # a second check with 3 frames joins the history, newest first; clicking the older one shows it again
        page.select_option("#check-frames", "3")
        page.click("#check-run")
        page.wait_for_function(f"document.getElementById('check-card').dataset.checkId !== '{rec['id']}'", timeout=60_000)
        page.wait_for_function("document.querySelectorAll('#check-history li').length === 3")
        ids = page.eval_on_selector_all("#check-history li", "els => els.map(e => e.dataset.checkId)")
        newest = httpx.get(f"{base}/api/checks").json()["checks"]
        assert ids == [c["id"] for c in newest] and newest[0]["frame_ids"] == list(range(frame_id - 2, frame_id + 1))
        assert newest[0]["frames_requested"] == 3 and page.locator("#check-frames-note").is_hidden()
        page.click(f"#check-history li[data-check-id='{rec['id']}']")
        assert page.get_attribute("#check-card", "data-check-id") == rec["id"]
        page.click(f"#check-history li[data-check-id='{first['id']}']")  # the check on fewer frames than asked says so
        assert page.text_content("#check-frames-note") == first["frames_note"] and page.locator("#check-frames-note").is_visible()
        # a board that is not in view: the page says what to change
        page.click("#check-board summary")
        page.fill("#check-squares", "11x8")
        page.click("#check-run")
        page.wait_for_selector("#check-error:not(.hidden)")
        assert "no 11x8 ChArUco board" in page.text_content("#check-error")
        ctx.close()
        # the refused check is the one answer >= 400 (and chromium's console line about it)
        unexpected = [p for p in problems if not (p.startswith("422 POST") or p.endswith("status of 422 (Unprocessable Entity)"))]
        assert unexpected == [], "\n".join(unexpected)
