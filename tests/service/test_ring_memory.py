"""The ring's memory: frames held as exact codes (bit for bit back), its bytes in /api/health, and a
frozen frame kept for a measurement session however many newer frames arrive."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from factories import plane_frame, wall_frame
from service_client import make_client

from service.frames import FrameGone, FrameRing
from service.packed import PackedFrame, Squeezed
from sim.source import SimConfig, SimSource


@cache
def _sim_frame():
    with SimSource(SimConfig(width=160, height=90, fps=0)) as src:
        return src.read()


def test_simulated_frame_is_held_in_codes_and_comes_back_bit_for_bit():
    frame = _sim_frame()
    packed = PackedFrame.pack(frame)
    assert packed.disparity.dtype == np.uint8 and packed.confidence.dtype == np.uint8  # 1/4 px below 64 px: a byte each
    assert isinstance(packed.disparity, Squeezed) and isinstance(packed.confidence, Squeezed)
    full = frame.image.nbytes + frame.disparity.nbytes + frame.confidence.nbytes
    assert packed.held_image is None  # the simulator makes it again: render plus a crop of its noise sheet
    codes = frame.disparity.size * 2  # 1 + 1 bytes a pixel for 4 + 4, no image
    assert packed.nbytes < 0.5 * codes  # compressed: the codes are mostly blocky (measured 0.35 at this size)
    assert packed.nbytes < 0.125 * full
    packed._last = None  # as when the pushed frame is gone
    assert np.array_equal(packed.image, frame.image)  # made again, bit for bit
    back = packed.unpack()
    assert back is not frame
    assert back.disparity.dtype == np.float32 and back.confidence.dtype == np.float32
    assert np.array_equal(back.image, frame.image)
    packed.keep_image()  # a frozen frame holds its image again
    assert np.array_equal(packed.held_image, frame.image) and packed.nbytes < frame.image.nbytes + 0.5 * codes
    assert np.array_equal(back.disparity.view(np.uint32), frame.disparity.view(np.uint32))  # NaN bits too
    assert np.array_equal(back.confidence.view(np.uint32), frame.confidence.view(np.uint32))
    assert (back.camera, back.baseline_m, back.meta) == (frame.camera, frame.baseline_m, frame.meta)
    assert packed.unpack() is back  # the same frame while anyone holds it


def test_simulated_images_are_made_again_bit_for_bit_under_every_lighting():
    """Each frame's noise is its own crop of the sheet: made again from the recipe, every image equals
    the one the source read (a recipe that ignored the crop would give one frame's image for all)."""
    for lighting in ("indoor", "mixed", "outdoor"):
        with SimSource(SimConfig(width=96, height=64, fps=0, lighting=lighting)) as src:
            frames = [src.read() for _ in range(4)]
        packs = [PackedFrame.pack(f) for f in frames]
        for f, p in zip(frames, packs):
            p._last = None
            assert p.held_image is None and np.array_equal(p.image, f.image), lighting
        assert len({f.image.tobytes() for f in frames}) > 1, lighting  # fresh noise per frame


def test_codes_that_do_not_compress_are_held_raw_and_all_come_back():
    # A noisy device's codes (every pixel its own level) would not shrink: they stay a plain array.
    frame = _sim_frame()
    rng = np.random.default_rng(3)
    d = (rng.integers(0, 255, frame.disparity.shape) / 4).astype(np.float32)  # 1/4 px below 64 px: byte codes
    c = (rng.integers(0, 256, frame.disparity.shape) / 255).astype(np.float32)
    packed = PackedFrame.pack(type(frame)(frame.image, d, frame.camera, frame.baseline_m, confidence=c))
    assert type(packed.disparity) is np.ndarray and packed.disparity.dtype == np.uint8
    assert type(packed.confidence) is np.ndarray and packed.confidence.dtype == np.uint8
    packed._last = None
    back = packed.unpack()
    assert np.array_equal(back.disparity.view(np.uint32), d.view(np.uint32))
    assert np.array_equal(back.confidence.view(np.uint32), c.view(np.uint32))


def test_unquantized_disparity_is_held_as_it_is():
    frame = plane_frame((0.0, 0.0, 1.0), 3.0, noise=0.3)  # float disparity, no 1/64 px steps
    packed = PackedFrame.pack(frame)
    assert packed.held_image is frame.image  # no recipe: the image is held
    assert packed.disparity is frame.disparity
    packed._last = None
    assert np.array_equal(packed.unpack().disparity, frame.disparity, equal_nan=True)


def test_frozen_frame_answers_after_a_minute_of_newer_frames_and_is_released_after_its_lease():
    now = [0.0]
    ring = FrameRing(capacity=4, max_frozen=64, keep_viewed=0, freeze_ttl_s=60.0, clock=lambda: now[0])
    kept = ring.push(wall_frame(0)).id
    ring.freeze(kept)
    for i in range(1, 600):  # 59.9 s of a 10 fps source
        now[0] = i / 10
        ring.push(wall_frame(i % 7))
    assert ring.get(kept).frozen  # measured 59.9 s after the freeze: still there, and kept 60 s more
    for i in range(600, 1190):  # 59 s more
        now[0] = i / 10
        ring.push(wall_frame(i % 7))
    assert ring.get(kept).frozen
    now[0] += 60.5
    ring.push(wall_frame(1))
    ring.push(wall_frame(2))
    with pytest.raises(FrameGone):  # nobody used it for 60 s: released, then evicted as the oldest
        ring.get(kept)


def test_health_states_the_ring_bytes_and_the_kernels(tmp_path):
    from build_tools import missing_build_tools

    with make_client(tmp_path) as c:
        from service_client import latest

        latest(c)
        ring = c.app.state.ring
        body = c.get("/api/health").json()
        assert body["ring_bytes"] > 0
        assert body["ring_bytes"] <= ring.nbytes + 10 * 48 * 64 * 8  # frames may arrive between the two reads
        # the session start built them for this machine where it can (tests/measure/test_aot.py); never a path or a reason
        assert body["kernels"] == ("numba, just in time" if missing_build_tools() else "built ahead of time")


def test_wide_disparity_in_fine_steps_is_held_as_int16_codes():
    frame = _sim_frame()
    d = frame.disparity.copy()
    d[0, :4] = [300.0, 0.015625, -2.5, np.nan]  # beyond a byte, a 1/64 px step, a negative value
    wide = PackedFrame.pack(type(frame)(frame.image, d, frame.camera, frame.baseline_m, confidence=frame.confidence))
    assert wide.disparity.dtype == np.int16
    wide._last = None
    assert np.array_equal(wide.unpack().disparity.view(np.uint32), d.view(np.uint32))


def test_health_answers_while_every_worker_thread_is_taken(tmp_path):
    # An export's chunks, thumbnails and lists run on the server's worker threads; health must not
    # wait for one. The threads' limiter is held at its only token, then health is asked for.
    import threading

    import anyio.to_thread
    from service_client import latest

    with make_client(tmp_path) as c:
        latest(c)
        assert c.get("/api/health").status_code == 200  # learns the next frame's size, lays the reserve

        async def take_every_thread():
            limiter = anyio.to_thread.current_default_thread_limiter()
            limiter.total_tokens = 1
            await limiter.acquire_on_behalf_of(take_every_thread)
            return limiter

        limiter = c.portal.call(take_every_thread)
        answered: list[int] = []
        asker = threading.Thread(target=lambda: answered.append(c.get("/api/health").status_code), daemon=True)
        try:
            asker.start()
            asker.join(20)
            assert answered == [200]  # answered while no worker thread was free
        finally:
            async def give_back():
                limiter.release_on_behalf_of(take_every_thread)
                limiter.total_tokens = 40

            c.portal.call(give_back)
            asker.join(20)


_SPECIALS = [np.nan, -0.0, 0.0, 0.25, 1 / 64, 1 / 128, 300.0, 511.984375, 512.0, -2.5, 1e-30, np.inf, -np.inf]


@settings(max_examples=300, deadline=None)
@given(
    values=st.lists(st.sampled_from(_SPECIALS) | st.floats(-600, 600, width=32) | st.integers(0, 2047).map(lambda k: k / 4),
                    min_size=1, max_size=48),
    nan_bits=st.sampled_from([0x7FC00000, 0xFFC00000, 0x7FC00001]),
    all_invalid=st.booleans(),
)
def test_any_disparity_comes_back_bit_for_bit(values, nan_bits, all_invalid):
    # Whatever a source sends (steps, fractions, -0.0, infinities, NaNs of other bits): the ring gives
    # back the very bits; only the holding (codes or the array itself) differs.
    frame = _sim_frame()
    d = frame.disparity.copy()
    d[0, : len(values)] = values
    d.view(np.uint32)[np.isnan(d)] = nan_bits
    if all_invalid:  # nothing matched: every pixel a NaN of those bits
        d.view(np.uint32)[:] = nan_bits
    packed = PackedFrame.pack(type(frame)(frame.image, d, frame.camera, frame.baseline_m))
    packed._last = None
    assert np.array_equal(packed.unpack().disparity.view(np.uint32), d.view(np.uint32))
