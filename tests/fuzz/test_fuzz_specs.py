"""Fuzzing source spec strings: ``kind[:target][?key=value&...]``.

Every spec either gives an unopened source or raises a SourceError (or another ValueError-typed
error) with a message; never another exception or a warning. No device is opened: ``make_source``
only parses (oak, v4l2), and of the cheap kinds only small ``sim`` specs are opened and read.
"""

from __future__ import annotations

from hypothesis import event, given
from hypothesis import strategies as st

from device import BACKENDS, SourceError, SourceSpec, make_source
from fuzzing import ODD_TEXT, typed_or_answer
from measure import Frame

KEYS = {
    "sim": ["distance", "lighting", "contention", "quantization", "seed", "fps", "width", "height", "target",
            "yaw", "roll", "mount", "standoff", "board_w", "board_l", "mode", "noise_px"],
    "oak": ["size", "preset", "fps", "subpixel", "lr_check", "extended_disparity", "confidence_threshold",
            "confidence_map", "search_timeout_ms", "mono_width", "mono_height"],
    "v4l2": ["size", "layout", "fourcc", "calib", "fps", "scale", "max_skew_s", "mode", "ndisp", "block", "p1",
             "p2", "uniqueness", "wls", "wls_lambda", "wls_sigma", "lr_confidence", "speckle_window",
             "speckle_range", "fill_left_band"],
    "replay": ["loop", "realtime", "speed", "start"],
    "middlebury": ["disparity"],
    "depthpng": ["baseline", "depth_scale", "fps", "loop"],
}
VALUES = st.one_of(
    st.sampled_from(["1", "0", "4", "2.5", "-1", "0.0", "nan", "inf", "-inf", "1e400", "1e-400", "0x10", "1_000",
                     " 3 ", "", "yes", "off", "stereo", "model", "indoor", "outdoor", "wall", "board", "64x48",
                     "96x64", "0x0", "99999999x1", "1e9", "MJPG", "sgbm", "gt", "HIGH_DETAIL", "side-by-side",
                     "9" * 40, "+", "%26", "%00", "a=b"]),
    st.integers(-(10**6), 10**6).map(str),
    st.floats(allow_nan=True).map(repr),
    ODD_TEXT,
)
# A plausible value per key (most specs should get past the parser and exercise the backends' checks).
GOOD = {
    "distance": ["4", "2", "0.8", "20"], "lighting": ["indoor", "mixed", "outdoor"], "contention": ["0", "0.5"],
    "quantization": ["0.25", "1"], "seed": ["0", "3"], "fps": ["0", "10", "15", "30"], "width": ["96", "64"],
    "height": ["64", "48"], "yaw": ["0", "30"], "roll": ["0", "5"], "mount": ["stand", "wall"],
    "standoff": ["0.5"], "board_w": ["0.6"], "board_l": ["0.9"], "mode": ["model", "stereo", "sgbm"],
    "noise_px": ["0.3"], "size": ["1280x720", "2560x720", "640x480"], "preset": ["default", "high_detail"],
    "subpixel": ["1", "0"], "lr_check": ["1"], "extended_disparity": ["0"], "confidence_threshold": ["200"],
    "confidence_map": ["1"], "search_timeout_ms": ["2000"], "mono_width": ["640"], "mono_height": ["400"],
    "layout": ["side-by-side", "two-nodes"], "fourcc": ["MJPG", "YUYV"], "calib": ["c.json"], "scale": ["0.5"],
    "max_skew_s": ["0.02"], "ndisp": ["64", "128"], "block": ["5"], "p1": ["200"], "p2": ["800"],
    "uniqueness": ["10"], "wls": ["0", "1"], "wls_lambda": ["8000"], "wls_sigma": ["1.5"], "lr_confidence": ["0"],
    "speckle_window": ["100"], "speckle_range": ["2"], "fill_left_band": ["1"], "loop": ["1", "0"],
    "realtime": ["0"], "speed": ["2"], "start": ["10"], "disparity": ["sgbm", "gt", "gt-int"],
    "baseline": ["0.075"], "depth_scale": ["1000"],
}
TARGETS = st.one_of(
    st.just(""),
    st.sampled_from(["poster", "person", "doorway", "boxes", "table", "/dev/video0", "/dev/video0,/dev/video2",
                     "/nonexistent/rec", "nonexistent", ".", "..", "/", "-", "a\x00b"]),
    ODD_TEXT,
)


@st.composite
def specs(draw: st.DrawFn) -> str:
    if draw(st.integers(0, 9)) == 0:
        return draw(ODD_TEXT)  # anything at all
    kind = draw(st.sampled_from(sorted(BACKENDS))) if draw(st.integers(0, 5)) else draw(
        st.one_of(st.sampled_from(["SIM", "usb", "", "sim ", "replay2"]), ODD_TEXT))
    keys = KEYS.get(kind.lower(), KEYS["sim"])
    pairs = []
    for _ in range(draw(st.integers(0, 4))):
        key = draw(st.sampled_from(keys)) if draw(st.integers(0, 5)) else draw(ODD_TEXT)
        value = draw(st.sampled_from(GOOD[key])) if key in GOOD and draw(st.integers(0, 2)) else draw(VALUES)
        pairs.append((key, value))
    spec = kind
    if draw(st.booleans()):
        spec += ":" + draw(TARGETS)
    if pairs or draw(st.booleans()):
        spec += "?" + "&".join(f"{k}={v}" if draw(st.integers(0, 19)) else k for k, v in pairs)
    return spec


def _small_sim(src) -> bool:
    cfg = getattr(src, "config", None)
    return src.info.kind == "sim" and cfg is not None and cfg.width * cfg.height <= 160 * 120


def _make_small(spec: str) -> str:
    """Most generated sim specs ask for 1280x720; make some small enough to read cheaply."""
    return spec + ("&" if "?" in spec else "?") + "width=96&height=64"


@given(specs(), st.booleans())
def test_source_specs_parse_or_raise_a_typed_error(spec, shrink):
    if shrink and spec.lower().startswith("sim"):
        spec = _make_small(spec)
    src = typed_or_answer(lambda: make_source(spec), (SourceError, ValueError))
    if src is None:
        event("rejected")
        return
    event(f"accepted {src.info.kind}")
    assert isinstance(src.info.kind, str) and src.info.kind in BACKENDS
    assert not src.is_open
    if _small_sim(src):
        def read() -> Frame:
            with src:
                return src.read(timeout_s=0.0)

        frame = typed_or_answer(read, (SourceError, ValueError))
        event("sim frame read" if frame is not None else "sim read rejected")
        if frame is not None:
            assert isinstance(frame, Frame) and frame.shape == (src.config.height, src.config.width)


@given(specs())
def test_parsed_specs_print_back_to_the_same_spec(spec):
    """``str(SourceSpec)`` is what logs and the service show and what a restart reopens: it parses back."""
    parsed = typed_or_answer(lambda: SourceSpec.parse(spec), SourceError)
    if parsed is None:
        return
    again = typed_or_answer(lambda: SourceSpec.parse(str(parsed)), SourceError)
    assert again == parsed, (spec, str(parsed))
