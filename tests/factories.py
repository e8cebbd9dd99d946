"""Synthetic frames, cameras, recordings and a fake source shared by the tests.

Every builder is deterministic (seeded) and has an exact ground truth, so a test asserts numbers, not
plausibility. The scenes live on three small rigs:

- the plane rig (320x240, f = 300 px, baseline 0.1 m): planes, a doorway, and the wall at 2 m that the
  fake source (`PlaneSource`) streams to the service tests;
- the recording rig (96x64, fx != fy, off-centre principal point): random frames with every optional
  field set, for byte-exact round trips;
- the simulator's rendered stereo pair (640x480, exact disparity) for the stereo-pair pipelines.

The poster rig of the accuracy tests (walls, contention outliers, clicks) is in `measure_synth.py`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from device import SourceBase, SourceDisconnected, SourceInfo, SourceNotFound, SourceTimeout
from device.formats.recording import RecordingWriter
from device.sources.sgbm import round_up_disparities
from measure import Frame, PinholeCamera
from sim import Truth


def camera(w: int, h: int, f: float, *, fy: float | None = None, cx: float | None = None, cy: float | None = None) -> PinholeCamera:
    """A pinhole camera of w x h px with focal length ``f`` px (``fy`` defaults to ``f``) whose principal
    point is the image centre ((w - 1) / 2, (h - 1) / 2) unless given."""
    return PinholeCamera(
        fx=f, fy=f if fy is None else fy, cx=(w - 1) / 2 if cx is None else cx, cy=(h - 1) / 2 if cy is None else cy,
        width=w, height=h,
    )


def flat_frame(w: int = 64, h: int = 48, d: float = 10.0, **kw) -> Frame:
    """Black image, disparity ``d`` px everywhere (NaN: none), f = 100 px, baseline 0.1 m; ``kw`` go to Frame."""
    return Frame(image=np.zeros((h, w, 3), np.uint8), disparity=np.full((h, w), d, np.float32), camera=camera(w, h, 100.0),
                 baseline_m=0.1, **kw)


# --- the plane rig -----------------------------------------------------------------------------------

SMALL_W, SMALL_H, SMALL_F, SMALL_B = 320, 240, 300.0, 0.1
SMALL_CAM = camera(SMALL_W, SMALL_H, SMALL_F)


def plane_frame(normal, k, *, quantum=None, noise=0.0, seed=0, outliers=0.0) -> Frame:
    """Disparity of the plane normal . P = k (m) seen by SMALL_CAM, optionally with Gaussian noise
    (``noise`` px), gross outliers (a fraction, x0.5-1.5) and quantization (``quantum`` px)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid((np.arange(SMALL_W) - SMALL_CAM.cx) / SMALL_F, (np.arange(SMALL_H) - SMALL_CAM.cy) / SMALL_F)
    z = k / (normal[0] * xs + normal[1] * ys + normal[2])
    d = SMALL_F * SMALL_B / z + rng.normal(0, noise, z.shape) if noise else SMALL_F * SMALL_B / z
    if outliers:
        bad = rng.random(d.shape) < outliers
        d = np.where(bad, d * rng.uniform(0.5, 1.5, d.shape), d)
    if quantum:
        d = np.round(d / quantum) * quantum
    return Frame(np.zeros((SMALL_H, SMALL_W, 3), np.uint8), d.astype(np.float32), SMALL_CAM, SMALL_B)


def true_length(frame: Frame, normal, k, p1, p2) -> float:
    """Length (m) between the points of the plane normal . P = k seen at pixels p1, p2 by ``frame``'s camera."""
    cam = frame.camera
    pts = []
    for x, y in (p1, p2):
        r = np.array([(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0])
        pts.append(r * k / (np.asarray(normal) @ r))
    return float(np.linalg.norm(pts[1] - pts[0]))


def doorway_frame(wall_z=3.0, back_z=6.0, opening=(100, 220), noise=0.1, seed=0) -> Frame:
    """A fronto-parallel wall at ``wall_z`` m with an opening (columns) onto a wall at ``back_z`` m,
    Gaussian noise ``noise`` px, quantized to 1/4 px."""
    rng = np.random.default_rng(seed)
    z = np.full((SMALL_H, SMALL_W), wall_z)
    z[:, opening[0] : opening[1]] = back_z
    d = SMALL_F * SMALL_B / z + rng.normal(0, noise, z.shape)
    d = np.round(d * 4) / 4
    return Frame(np.zeros((SMALL_H, SMALL_W, 3), np.uint8), d.astype(np.float32), SMALL_CAM, SMALL_B)


def boxes_frame(step: float, seed: int = 0) -> Frame:
    """Two boxes at 9.4 px with a background ``step`` (relative depth) farther between them, smooth
    correlated noise (sigma 0.1 px over ~5 px) and boxes fattened 3 px into the gap as SGBM does;
    400x200, f = 500 px, baseline 0.06 m."""
    import cv2

    h, w = 200, 400
    d = np.full((h, w), 9.4, np.float32)
    d[:, 153:247] = 9.4 / (1.0 + step)
    noise = cv2.GaussianBlur(np.random.default_rng(seed).normal(0.0, 0.5, (h, w)).astype(np.float32), (0, 0), 2.5)
    d += noise * np.float32(0.1 / noise.std())
    return Frame(np.zeros((h, w, 3), np.uint8), d, camera(w, h, 500.0, cx=w / 2, cy=h / 2), baseline_m=0.06)


# --- the wall the fake source streams (service tests) -------------------------------------------------

WALL_DISP = 15.0
WALL_Z = SMALL_F * SMALL_B / WALL_DISP  # 2.0 m: every pixel sees a fronto-parallel wall


def wall_frame(index: int) -> Frame:
    """Frame number ``index`` of the fake source: the wall at WALL_Z on the plane rig, an 8x8 hole in the
    corner (so the colour map has "no data" to paint), a colour gradient whose blue channel encodes
    the index, and meta {"source": "plane", "index": index}."""
    yy, xx = np.mgrid[0:SMALL_H, 0:SMALL_W]
    image = np.stack([(xx * 255 // SMALL_W), (yy * 255 // SMALL_H), np.full_like(xx, (index * 37) % 256)], -1).astype(np.uint8)
    disparity = np.full((SMALL_H, SMALL_W), WALL_DISP, np.float32)
    disparity[:8, :8] = np.nan
    return Frame(image, disparity, SMALL_CAM, SMALL_B, timestamp=index / 30, meta={"source": "plane", "index": index})


def hilly_frame(index: int) -> Frame:
    """The wall frame with a disparity that varies per pixel (10-20 px), doffs 1.5 px and a hole."""
    f = wall_frame(index)
    yy, xx = np.mgrid[0:SMALL_H, 0:SMALL_W]
    disparity = (10.0 + 10.0 * xx / SMALL_W + 0.37 * np.sin(yy / 7.0)).astype(np.float32)
    disparity[50:60, 100:110] = np.nan
    return Frame(f.image, disparity, f.camera, f.baseline_m, doffs=1.5, timestamp=f.timestamp, meta=dict(f.meta))


def wall_length(p1, p2) -> float:
    """True length (m) between pixels p1, p2 on the wall of `wall_frame`."""
    return float(np.hypot(p2[0] - p1[0], p2[1] - p1[1]) * WALL_Z / SMALL_F)


class FakeClock:
    """Stands in for the ``time`` module of a paced source (monkeypatch it over ``module.time``): the
    clock moves only when slept on or when the test moves ``now``, and ``sleeps`` lists every requested
    sleep (s), so pacing is asserted without wall-clock time. A negative sleep raises, as time.sleep does."""

    def __init__(self, now: float = 1000.0) -> None:
        self.now = now
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        if s < 0:
            raise ValueError(f"sleep length must be non-negative (asked for {s} s)")
        self.sleeps.append(s)
        self.now += s


class PlaneSource(SourceBase):
    """The fake source: frame n is ``frame(n)`` (the wall at 2 m by default). It optionally disconnects
    after ``fail_after`` frames, refuses ``state["refuse"]`` reopenings, and with ``state["gate"]`` (a
    semaphore) sends a frame only when the test releases one."""

    def __init__(self, fail_after: int | None = None, state: dict | None = None, frame: Callable[[int], Frame] = wall_frame) -> None:
        self.info = SourceInfo(kind="plane", name="Fake plane", serial="F1", width=SMALL_W, height=SMALL_H, fps=30.0)
        self.fail_after = fail_after
        self.state = state if state is not None else {}
        self.frame = frame
        self.n = 0

    def open(self) -> None:
        refuse = self.state.get("refuse", 0)
        if refuse:
            self.state["refuse"] = refuse - 1
            raise SourceNotFound("fake plane unplugged; plug it back in")
        super().open()

    def read(self, timeout_s: float = 1.0) -> Frame:
        gate = self.state.get("gate")
        if gate is not None and not gate.acquire(timeout=timeout_s):
            raise SourceTimeout("fake plane: no frame released by the test")
        self.n += 1
        if self.fail_after is not None and self.n > self.fail_after:
            raise SourceDisconnected("fake plane: cable pulled (XLink error)")
        return self.frame(self.n)


# --- the recording rig ---------------------------------------------------------------------------------

SYNTH_W, SYNTH_H = 96, 64
SYNTH_CAM = PinholeCamera(fx=80.0, fy=81.5, cx=47.25, cy=31.75, width=SYNTH_W, height=SYNTH_H)
SYNTH_INFO = SourceInfo(kind="synthetic", name="unit", serial="S1", width=SYNTH_W, height=SYNTH_H, fps=30.0,
                        extra={"obj": object(), "n": 2})


def synthetic_frame(k: int, w: int = SYNTH_W, h: int = SYNTH_H, confidence: bool = True) -> Frame:
    """Deterministic frame number k: random colour, disparity in [0.5, 300) px with 10 % holes, doffs,
    confidence, a timestamp and meta that a recording must keep (numpy scalar, Truth) or drop (object)."""
    rng = np.random.default_rng(1000 + k)
    cam = SYNTH_CAM if (w, h) == (SYNTH_W, SYNTH_H) else camera(w, h, 80.0, fy=81.5, cx=w / 2, cy=h / 2)
    disp = rng.uniform(0.5, 300.0, (h, w)).astype(np.float32)
    disp[rng.random((h, w)) < 0.1] = np.nan
    return Frame(
        image=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        disparity=disp,
        camera=cam,
        baseline_m=0.0625,
        doffs=1.5,
        confidence=rng.random((h, w)).astype(np.float32) if confidence else None,
        timestamp=1000.0 + k / 30.0,
        meta={
            "source": "synthetic",
            "k": k,
            "gain": np.float32(1.25),
            "truth": Truth(np.ones((h, w)), (0.0, 0.1, 2.0), (0.5, 0.1, 2.0), (10.0, 20.0), (60.0, 20.0), 0.5, "poster-width", False),
            "handle": object(),
        },
    )


def record(path: Path, n: int, **kw) -> list[Frame]:
    """Write synthetic frames 0..n-1 as a recording at ``path`` (``kw`` go to RecordingWriter); returns them."""
    frames = [synthetic_frame(k) for k in range(n)]
    with RecordingWriter(path, SYNTH_INFO, **kw) as w:
        for k, f in enumerate(frames):
            assert w.write(f) == k
    return frames


def assert_same_frame(got: Frame, want: Frame) -> None:
    """A recorded frame read back: colour bit for bit, the NaN pattern identical, disparity within the
    format's 1/128 px, confidence within 1/510, camera, baseline, doffs and timestamp equal."""
    assert got.image.dtype == np.uint8 and np.array_equal(got.image, want.image), "colour must round-trip bit for bit"
    assert np.array_equal(np.isnan(got.disparity), np.isnan(want.disparity)), "NaN pattern must be identical"
    ok = ~np.isnan(want.disparity)
    assert np.max(np.abs(got.disparity[ok] - want.disparity[ok])) <= 1 / 128
    assert got.camera == want.camera and got.baseline_m == want.baseline_m and got.doffs == want.doffs
    assert got.timestamp == want.timestamp
    if want.confidence is None:
        assert got.confidence is None
    else:
        assert np.max(np.abs(got.confidence - want.confidence)) <= 1 / 510 + 1e-7


# --- the simulator's rendered stereo pair ---------------------------------------------------------------

@dataclass(frozen=True)
class RenderedPair:
    """The simulator's rendered stereo pair of one scene (640x480) with its exact disparity."""

    left: np.ndarray
    right: np.ndarray
    k: np.ndarray  # 3x3 intrinsics of both (identical) cameras, px
    baseline_m: float
    gt: np.ndarray  # exact disparity, px; NaN where nothing was hit
    view: object  # sim.scenes view: .camera, .truth()

    @property
    def ndisp(self) -> int:
        return round_up_disparities(int(np.nanmax(self.gt) * 1.25) + 8)

    def assert_matched(self, frame) -> None:
        """The simulator's textures and sky change as it evolves, so no coverage figure is pinned here:
        where SGBM matched, it must agree with the exact disparity."""
        matched = np.isfinite(self.gt) & np.isfinite(frame.disparity)
        assert matched.sum() > 0.3 * self.gt.size
        assert np.median(np.abs(frame.disparity[matched] - self.gt[matched])) < 0.5


def rendered_pair(scene: str, distance: float) -> RenderedPair:
    """``scene`` ("poster", "boxes", ...) at ``distance`` m rendered by the simulator's indoor model (seed 0)."""
    from sim import scenes as sim_scenes
    from sim.scenario import make_model
    from sim.stereo import stereo_pair, true_disparity

    params = sim_scenes.SceneParams(scene=scene, distance_m=distance, width=640, height=480)
    model = make_model("indoor")
    left, right = stereo_pair(params, model, np.random.default_rng(0))
    view = sim_scenes.get_view(params)
    cam = view.camera
    k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
    return RenderedPair(left, right, k, model.baseline_wide_m, true_disparity(params, model), view)


def write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0, fourcc: str = "FFV1") -> Path:
    """``frames`` (BGR, one size) as a video file through OpenCV's FFmpeg backend (FFV1: lossless)."""
    import cv2

    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened(), f"OpenCV cannot write {fourcc}"
    for f in frames:
        writer.write(f)
    writer.release()
    return path
