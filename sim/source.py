"""The simulated rig as a Source: ``open_source("sim:poster?distance=6&lighting=outdoor&seed=3")``.

The spec's target is the scene ("sim" alone is a poster at 4 m under indoor light); the options are
:class:`SimConfig`'s fields, each spelled, bounded and explained once in its metadata and parsed by
``device.configs`` (the table in docs/usage.md is generated from it). Besides them, any SensorModel
field may be set by name (e.g. ``noise_px=0.3``). ``mode=stereo`` renders a left/right pair and runs
it through OpenCV SGBM instead of the sensor model; ``baseline_error=0.02`` makes the frames report a
baseline 2 % long (a wrong calibration for `depthruler check` to find).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from device import configs
from device.base import Backend, SourceBase, SourceInfo, SourceSpec
from device.errors import SourceError, SourceNotFound, SourceTimeout
from measure import Frame, check_options, option

from sim.scenario import make_model, simulate_frame
from sim.scenes import BOARD_M, CHARUCO_BOARD, MOUNTS, SCENES, SceneError, SceneParams, get_view, resolve_target
from sim.sensor import PROFILES, SensorError, SensorModel, get_profile
from sim import textures
from sim.textures import LIGHTING

MODES = ("model", "stereo")


def _sensor_keys() -> dict[str, type]:
    """SensorModel fields a spec may set by name (lighting, contention and quantization have their own keys)."""
    kinds = {"bool": bool, "int": int, "str": str}
    return {f.name: kinds.get(str(f.type), float) for f in fields(SensorModel)
            if f.name not in ("lighting", "contention", "quantization")}


@dataclass(frozen=True)
class SimConfig:
    """What the simulated source shows and how fast: each field's spelling, bounds and help are in
    its metadata (docs/usage.md "Source options" lists them)."""

    scene: str = option("poster", target=True, key="scene", choices=tuple(SCENES), help="the scene shown")
    target: str | None = option(None, example="poster-width", help="which object of the scene the truth and the clicks are on (default: the scene's)")
    distance_m: float = option(4.0, key="distance", min=0.0, min_open=True, unit="m", help="distance of the scene from the camera")
    lighting: str = option("indoor", choices=tuple(LIGHTING), help="lighting: sets the sensor noise and the holes")
    profile: str = option("stress", choices=tuple(PROFILES), help="sensor profile (sim.sensor.PROFILES): stress, or paper (the paper's tablet)")
    contention: float | None = option(None, min=0.0, max=0.5, default_text="the profile's", help="share of wrong-pair matches in contended regions")
    quantization: float | None = option(None, min=0.0, min_open=True, unit="px", default_text="the profile's", help="disparity step (1 = integer)")
    seed: int = option(0, min=0, help="seed of the sensor noise")
    fps: float = option(10.0, min=0.0, unit="frames/s", help="frame rate (0 = as fast as frames are read)")
    width: int = option(1280, min=16, unit="px", help="image width")
    height: int = option(720, min=16, unit="px", help="image height")
    yaw_deg: float = option(0.0, key="yaw", unit="deg", help="turn of the scene about the vertical axis")
    roll_deg: float = option(0.0, key="roll", unit="deg", help="roll of the scene about the viewing axis")
    mount: str | None = option(None, choices=MOUNTS, default_text="the profile's", help="the poster on its stand, or glued on the wall: stand | wall")
    standoff_m: float = option(1.0, key="standoff", min=0.0, unit="m", help="the board in front of the wall")
    board_w_m: float = option(BOARD_M[0], key="board_w", min=0.0, min_open=True, unit="m", help="the poster's width")
    board_l_m: float = option(BOARD_M[1], key="board_l", min=0.0, min_open=True, unit="m", help="the poster's length")
    mode: str = option("model", choices=MODES, help="model: the sensor model; stereo: rendered pair through SGBM")
    baseline_error: float = option(0.0, min=-0.5, max=0.5, min_open=True, max_open=True,
                                   help="the frames report a baseline off by this share: a wrong calibration for the check to find")
    squares: str = option(f"{CHARUCO_BOARD[0]}x{CHARUCO_BOARD[1]}", example="9x6", help="the charuco scene's board: COLSxROWS squares")
    square_mm: float = option(CHARUCO_BOARD[2] * 1000, min=0.0, min_open=True, unit="mm", help="the charuco board's square side")
    marker_mm: float = option(CHARUCO_BOARD[3] * 1000, min=0.0, min_open=True, unit="mm", help="the charuco board's marker side")
    dictionary: str = option(CHARUCO_BOARD[4], example="DICT_4X4_50", help="the charuco board's ArUco dictionary")
    sensor: tuple[tuple[str, object], ...] = option(factory=tuple, extras=_sensor_keys, example=(("noise_px", 0.3),),
                                                    help="any other SensorModel field by name, e.g. noise_px=0.3")

    def __post_init__(self) -> None:
        if self.scene not in SCENES:  # a missing thing, not a bad number: SourceNotFound
            raise SourceNotFound(f"unknown sim scene {self.scene!r}; use one of {', '.join(SCENES)} (e.g. 'sim:person')")
        check_options(self, SourceError, "sim option ")
        try:  # fail when the config is made, not at the first read
            self.scene_params()
            resolve_target(self.scene, self.target)
            self.sensor_model()
        except (SceneError, SensorError) as exc:
            raise SourceError(f"sim source: {exc}") from exc

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


def config_from_spec(spec: SourceSpec) -> SimConfig:
    """Parse ``sim[:scene][?key=value...]`` (device.configs); bad keys or values raise SourceError naming the allowed ones."""
    return configs.from_spec(SimConfig, spec)


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
            # The view (cached) holds its renders; the textures they were painted from are needed again
            # only for another view, and a source shows one: their 25 MB at 1280x720 go back.
            textures.noise_tile.cache_clear()
            textures.poster_image.cache_clear()
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
            frame, _ = simulate_frame(cfg.scene_params(), self.model, rng, target=cfg.target, meta=meta, rebuild_image=True)
        if cfg.baseline_error:
            frame = replace(frame, baseline_m=frame.baseline_m * (1.0 + cfg.baseline_error))
        return frame


def _with_state(info: SourceInfo, state: str) -> SourceInfo:
    return replace(info, state=state)


# Registered under the entry-point group depthruler.sources (pyproject.toml): the kind "sim".
BACKEND = Backend("sim.source", "SimConfig", "SimSource", "scene")
