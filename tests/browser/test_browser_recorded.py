"""Every recorded source gets the replay bar a native recording has: a ROS 2 bag (the simulated poster
as realsense-ros writes it) and a side-by-side FFV1 stereo video of the simulator's rendered pair. Pause,
step, step back and scrub drive each, the position reads "frame k of n", and the CSV row of a
measurement names the source kind, the recording and the frame it was made on."""

from __future__ import annotations

import csv
import io

import cv2
import httpx
import numpy as np
import pytest

from bag_writers import make_capture, write_ros_bag
from browser_helpers import serve, watch
from factories import rendered_pair

pytestmark = [pytest.mark.browser, pytest.mark.slow]

VIDEO_FRAMES = 4


def write_video(path, frames, fps: float = 10.0):
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"FFV1"), fps, (w, h))
    assert writer.isOpened(), "OpenCV cannot write FFV1"
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def write_yaml(path, k, baseline_m: float, size) -> str:
    """The pair's calibration as OpenCV's stereo_calib writes it: same K, no distortion, R = I."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, value in (("M1", k), ("D1", np.zeros((1, 5))), ("M2", k), ("D2", np.zeros((1, 5))), ("R", np.eye(3)),
                        ("T", np.array([[-baseline_m], [0.0], [0.0]]))):  # fmt: skip
        fs.write(name, np.asarray(value, np.float64))
    fs.write("image_width", int(size[0]))
    fs.write("image_height", int(size[1]))
    fs.release()
    return str(path)


@pytest.fixture(scope="module", params=["bag", "video"])
def recorded(request, tmp_path_factory):
    """(base URL, source kind, recording name, frames in it)."""
    folder = tmp_path_factory.mktemp(request.param)
    if request.param == "bag":
        bag = write_ros_bag(folder / "desk-bag", make_capture(), "mcap", "realsense-ros")
        spec, name, n = f"bag:{bag}?loop=1&realtime=1", "desk-bag", len(make_capture().frames)
    else:
        pair = rendered_pair("poster", 2.0)
        frames = [np.hstack([pair.left, pair.right])] * VIDEO_FRAMES  # which frame is shown: its index in meta
        video = write_video(folder / "hall.mkv", frames)
        yaml = write_yaml(folder / "hall.yaml", pair.k, pair.baseline_m, (640, 480))
        spec, name, n = f"video:{video}?calib={yaml}&ndisp={pair.ndisp}&loop=1&realtime=1", "hall.mkv", VIDEO_FRAMES
    with serve(folder, spec) as base:
        yield base, request.param, name, n


def test_recorded_source_has_the_replay_bar_and_the_csv_names_it(recorded, browser):
    server, kind, name, frames = recorded
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    problems = watch(page)
    page.goto(server + "/")
    page.wait_for_function("document.getElementById('canvas').dataset.frameId", timeout=60_000)
    page.wait_for_function("k => document.getElementById('source-badge').dataset.kind === k", arg=kind)
    assert page.text_content("#source-badge") == f"{kind.upper()} {name}"
    assert page.locator("#replay-bar").is_visible()
    status = httpx.get(f"{server}/api/source").json()["replay"]
    assert (status["kind"], status["recording"], status["frames"]) == (kind, name, frames)

    def shown_index() -> int:  # the index in the recording of the frame on screen, from the server
        fid = page.get_attribute("#canvas", "data-frame-id")
        return httpx.get(f"{server}/api/frames/{fid}").json()["replay_index"]

    def at(i: int) -> None:  # the page shows frame i, and says so 1-based
        page.wait_for_function("n => document.getElementById('frame-tag').dataset.index === String(n)", arg=i, timeout=30_000)
        assert shown_index() == i
        assert page.text_content("#replay-pos") == f"frame {i + 1} of {frames}"
        assert f"frame {i + 1} of {frames}" in page.text_content("#frame-tag")

    page.click("#replay-play")  # pause
    page.wait_for_function("document.getElementById('replay-bar').dataset.paused === '1'")
    paused_at = None
    while (now := httpx.get(f"{server}/api/source").json()["replay"]["index"]) != paused_at:
        paused_at = now  # a read already under way when the pause came may still land
        page.wait_for_timeout(600)
    at(paused_at)
    page.click("#replay-step")
    at((paused_at + 1) % frames)
    page.click("#replay-back")
    at(paused_at)
    page.locator("#replay-scrub").fill(str(frames - 1))  # scrub to the last frame
    at(frames - 1)

    # measure on it: the CSV row names the source kind, the recording and the frame (1-based on screen)
    page.click("#freeze")
    page.wait_for_function("document.getElementById('canvas').dataset.frozen === '1'")
    box = page.locator("#canvas").bounding_box()
    page.mouse.click(box["x"] + box["width"] * 0.4, box["y"] + box["height"] * 0.5)
    page.mouse.click(box["x"] + box["width"] * 0.6, box["y"] + box["height"] * 0.5)
    page.wait_for_function("document.getElementById('distance').dataset.metres", timeout=30_000)
    mid = int(page.get_attribute("#distance", "data-id"))
    rows = list(csv.DictReader(io.StringIO(httpx.get(f"{server}/api/measurements.csv").text, newline="")))
    row = next(r for r in rows if int(r["id"]) == mid)
    assert (row["source_kind"], row["recording"], row["frame_index"]) == (kind, name, str(frames - 1))
    assert row["source"].startswith(f"{kind}:")
    page.wait_for_function("document.querySelectorAll('#history li').length === 1")
    assert page.text_content("#history li .h-meta").startswith(f"{kind} {name} · frame {frames}")

    # reopened from the history, it is marked as the saved measurement, on its frame of the recording
    page.click("#replay-play")  # play again: goes live, the recording moves on
    page.wait_for_function("document.getElementById('replay-bar').dataset.paused === ''")
    page.click("#history li")
    page.wait_for_function("id => document.getElementById('saved').dataset.id === id", arg=str(mid))
    assert page.text_content("#frame-tag").startswith(f"saved #{mid} · {name} · frame {frames} of {frames}")
    assert page.locator("#saved").is_visible()
    assert problems == [], "\n".join(problems)
