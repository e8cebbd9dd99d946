"""The simulated rig as a Source: ``open_source("sim:poster?distance=6&lighting=outdoor&seed=3")``.

Spec keys: profile ("stress" | "paper", sim.sensor.PROFILES: sensor fields and the poster's mount),
distance (m), lighting, contention, quantization (both default to the profile's), seed, fps (0 = as
fast as read), width, height, target, yaw (deg), roll (deg), mount ("stand" | "wall": the poster board
on its legs or glued on the wall; default: the profile's), standoff (m, the board in front of the
wall; fixed per source), board_w and board_l (m, the poster's size), squares ("7x5"), square_mm,
marker_mm and dictionary (the "charuco" scene's printed ChArUco board, as `depthruler calibrate` and
`check` take them), mode ("model": the sensor model; "stereo": rendered left/right images
through OpenCV SGBM), baseline_error (the frames report a baseline off by this share, e.g. 0.02: a camera
whose calibration is wrong, for `depthruler check` to find), and any SensorModel field by name (e.g. noise_px=0.3).
The scene names the spec target: "sim" alone is a poster at 4 m under indoor light.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from device.base import Backend, SourceBase, SourceInfo, SourceSpec, parse_flag
from device.errors import SourceError, SourceNotFound, SourceTimeout
from measure import Frame

from sim.scenario import make_model, simulate_frame
from sim.scenes import BOARD_M, CHARUCO_BOARD, SCENES, SceneError, SceneParams, get_view, resolve_target
from sim.sensor import SensorError, SensorModel, get_profile
from sim.textures import LIGHTING

MODES = ("model", "stereo")


@dataclass(frozen=True)
class SimConfig:
    """What the simulated source shows and how fast (see the module docstring for the spec keys)."""

    scene: str = "poster"
    target: str | None = None
    distance_m: float = 4.0
    lighting: str = "indoor"
    profile: str = "stress"
    contention: float | None = None  # None = the profile's
    quantization: float | None = None
    seed: int = 0
    fps: float = 10.0
    width: int = 1280
    height: int = 720
    yaw_deg: float = 0.0
    roll_deg: float = 0.0
    mount: str | None = None  # None = the profile's
    standoff_m: float = 1.0
    board_w_m: float = BOARD_M[0]
    board_l_m: float = BOARD_M[1]
    mode: str = "model"
    baseline_error: float = 0.0  # the reported baseline is (1 + this) x the true one: a wrong calibration
    squares: str = f"{CHARUCO_BOARD[0]}x{CHARUCO_BOARD[1]}"
    square_mm: float = CHARUCO_BOARD[2] * 1000
    marker_mm: float = CHARUCO_BOARD[3] * 1000
    dictionary: str = CHARUCO_BOARD[4]
    sensor: tuple[tuple[str, object], ...] = field(default_factory=tuple)  # extra SensorModel overrides

    def __post_init__(self) -> None:
        if self.scene not in SCENES:
            raise SourceNotFound(f"unknown sim scene {self.scene!r}; use one of {', '.join(SCENES)} (e.g. 'sim:person')")
        if self.mode not in MODES:
            raise SourceError(f"sim mode={self.mode!r} is unknown; use one of {', '.join(MODES)}")
        if self.fps < 0:
            raise SourceError(f"sim fps={self.fps} must be >= 0 (0 = as fast as frames are read)")
        if not (-0.5 < self.baseline_error < 0.5):
            raise SourceError(f"sim baseline_error={self.baseline_error} must lie in (-0.5, 0.5), e.g. 0.02 for 2 % long")

    def scene_params(self) -> SceneParams:
        mount = get_profile(self.profile).mount if self.mount is None else self.mount
        poster: dict[str, Any] = dict(mount=mount, standoff_m=self.standoff_m, board_w_m=self.board_w_m,
                                      board_l_m=self.board_l_m) if self.scene == "poster" else {}
        if self.scene == "charuco":
            poster = dict(mount=mount, standoff_m=self.standoff_m, charuco=self.charuco())
        return SceneParams(self.scene, self.distance_m, self.yaw_deg, self.roll_deg, self.width, self.height, **poster)

    def charuco(self) -> tuple[int, int, float, float, str]:
        """The printed board of the "charuco" scene: (squares across, down, square m, marker m, dictionary)."""
        x, _, y = self.squares.lower().partition("x")
        if not (x.isdigit() and y.isdigit()):
            raise SceneError(f"squares={self.squares!r} is not COLSxROWS, e.g. squares=7x5")
        import cv2

        if not hasattr(cv2.aruco, self.dictionary):
            raise SceneError(f"unknown ArUco dictionary {self.dictionary!r}; use e.g. DICT_5X5_100, DICT_4X4_50")
        return (int(x), int(y), self.square_mm / 1000.0, self.marker_mm / 1000.0, self.dictionary)

    def sensor_model(self) -> SensorModel:
        return make_model(self.lighting, self.profile, contention=self.contention, quantization=self.quantization,
                          **dict(self.sensor))


_KEYS = {  # spec key -> (SimConfig field, parser)
    "distance": ("distance_m", float),
    "lighting": ("lighting", str),
    "profile": ("profile", str),
    "contention": ("contention", float),
    "quantization": ("quantization", float),
    "seed": ("seed", int),
    "fps": ("fps", float),
    "width": ("width", int),
    "height": ("height", int),
    "target": ("target", str),
    "yaw": ("yaw_deg", float),
    "roll": ("roll_deg", float),
    "mount": ("mount", str),
    "standoff": ("standoff_m", float),
    "board_w": ("board_w_m", float),
    "board_l": ("board_l_m", float),
    "mode": ("mode", str),
    "baseline_error": ("baseline_error", float),
    "squares": ("squares", str),
    "square_mm": ("square_mm", float),
    "marker_mm": ("marker_mm", float),
    "dictionary": ("dictionary", str),
}


def _sensor_parsers() -> dict[str, object]:
    out: dict[str, object] = {}
    for f in fields(SensorModel):
        kind = str(f.type)
        out[f.name] = parse_flag if kind == "bool" else int if kind == "int" else str if kind == "str" else float
    return out


def config_from_spec(spec: SourceSpec) -> SimConfig:
    """Parse ``sim[:scene][?key=value...]``; bad keys or values raise SourceError naming the allowed ones."""
    sensor_parsers = _sensor_parsers()
    kwargs: dict[str, object] = {"scene": spec.target or "poster"}
    sensor: dict[str, object] = {}
    for key, text in spec.params.items():
        if key in _KEYS:
            name, parse = _KEYS[key]
            store, parse_fn = kwargs, parse
        elif key in sensor_parsers and key not in ("lighting", "contention", "quantization"):
            name, store, parse_fn = key, sensor, sensor_parsers[key]
        else:
            allowed = sorted(set(_KEYS) | (set(sensor_parsers) - {"lighting", "contention", "quantization"}))
            raise SourceError(f"unknown sim option {key!r} in {str(spec)!r}; use any of: {', '.join(allowed)}")
        try:
            store[name] = parse_fn(text)  # type: ignore[operator]
        except ValueError as exc:
            raise SourceError(f"sim option {key}={text!r} is not valid: {exc}") from exc
    lighting = kwargs.get("lighting", "indoor")
    if lighting not in LIGHTING:
        raise SourceError(f"sim lighting={lighting!r} is unknown; use one of {', '.join(LIGHTING)}")
    try:
        get_profile(str(kwargs.get("profile", "stress")))
    except SensorError as exc:
        raise SourceError(f"sim source {str(spec)!r}: {exc}") from exc
    config = SimConfig(**kwargs, sensor=tuple(sorted(sensor.items())))  # type: ignore[arg-type]
    try:  # fail at parse time, not at the first read
        config.scene_params()
        resolve_target(config.scene, config.target)
        config.sensor_model()
    except (SceneError, SensorError) as exc:
        raise SourceError(f"sim source {str(spec)!r}: {exc}") from exc
    return config


class SimSource(SourceBase):
    """Frames of the simulated rig, forever: same scene, fresh sensor noise per frame, paced at ``fps``."""

    def __init__(self, config: SimConfig = SimConfig()) -> None:
        self.config = config
        self.model = config.sensor_model()
        self.info = SourceInfo(
            kind="sim",
            name=f"simulated rig: {config.scene} at {config.distance_m:g} m, {config.lighting}",
            serial=f"sim-{config.scene}-{config.seed}",
            width=config.width,
            height=config.height,
            fps=config.fps,
            state="closed",
            extra={"mode": config.mode, "profile": config.profile, "baseline_m": self.model.baseline_wide_m},
        )
        self._index = 0
        self._t0 = 0.0

    def open(self) -> None:
        try:
            view = get_view(self.config.scene_params())
            view.truth(self.config.target)
        except SceneError as exc:
            raise SourceError(f"sim source cannot show this scene: {exc}") from exc
        self._index = 0
        self._t0 = time.monotonic()
        self.info = _with_state(self.info, "streaming")
        super().open()

    def close(self) -> None:
        self.info = _with_state(self.info, "closed")
        super().close()

    def read(self, timeout_s: float = 1.0) -> Frame:
        if not self.is_open:
            raise SourceError("the sim source is not open; call open() or use it as a context manager")
        cfg = self.config
        if cfg.fps > 0:
            due = self._t0 + self._index / cfg.fps
            wait = due - time.monotonic()
            if wait > timeout_s:
                time.sleep(max(timeout_s, 0.0))
                raise SourceTimeout(f"next sim frame is due in {wait:.3f} s, after the {timeout_s} s timeout; "
                                    "read with a longer timeout or a higher fps")
            if wait > 0:
                time.sleep(wait)
        i = self._index
        self._index += 1
        rng = np.random.default_rng([cfg.seed, i])
        meta = {"frame_index": i, "seed": cfg.seed, "mode": cfg.mode}
        if cfg.mode == "stereo":
            from sim.stereo import stereo_frame

            frame, _ = stereo_frame(cfg.scene_params(), self.model, rng, target=cfg.target, meta=meta)
        else:
            frame, _ = simulate_frame(cfg.scene_params(), self.model, rng, target=cfg.target, meta=meta)
        if cfg.baseline_error:
            frame = replace(frame, baseline_m=frame.baseline_m * (1.0 + cfg.baseline_error))
        return frame


def _with_state(info: SourceInfo, state: str) -> SourceInfo:
    return replace(info, state=state)


# Registered under the entry-point group depthruler.sources (pyproject.toml): the kind "sim".
BACKEND = Backend("sim.source", "SimConfig", "SimSource", "scene")
