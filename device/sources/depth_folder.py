"""A folder of 16-bit depth PNGs with a JSON of intrinsics as a source: ``depthpng:DIR``.

Layouts read (the ones Open3D's RealSense / Azure Kinect recorders and the ZED export tools write):

- ``DIR/depth/*.png`` with ``DIR/color/*.jpg|png`` (or ``rgb/``, ``image/``, ``left/``), or
- flat ``DIR/depth000000.png`` with ``DIR/left000000.png`` (or ``color``/``rgb``/``image`` prefixes).

Colour and depth pair up in sorted file-name order. Without colour images the source shows a grey
rendering of the depth (``meta["image"] == "depth-visualisation"``) so there is still something to click.

Intrinsics JSON: ``camera_intrinsic.json``, ``intrinsic.json``, ``intrinsics.json`` or ``camera.json``
(else the only ``*.json`` in DIR), holding either Open3D's ``{"width", "height", "intrinsic_matrix":
[fx, 0, 0, 0, fy, 0, cx, cy, 1]}`` (column-major; a row-major 3x3 is recognised too) or flat
``fx, fy, cx, cy`` (``ppx``/``ppy`` accepted). Optional keys: ``depth_scale`` (PNG units per metre,
Open3D's convention; default 1000 = millimetres), ``baseline_m``, ``doffs``, ``fps``.

Depth to disparity: frames carry disparity (docs/design.md), ``d = fx * B / Z - doffs``. A depth
camera's baseline is rarely in these files, so ``B`` defaults to a nominal ``DEFAULT_BASELINE_M``
(0.075 m) unless the JSON or the spec (``?baseline=0.12``) gives it. Any ``B`` reproduces ``Z``
exactly (``Z = fx * B / (d + doffs)``), so measured lengths do not depend on it. PNG value 0 = no depth.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from measure import Frame, MeasureError, PinholeCamera, check_options, option

from device import configs
from device.base import SourceBase, SourceInfo, SourceSpec
from device.errors import CalibrationError, RecordingError, SourceError, SourceNotFound
from device.formats.recording import EndOfRecording

DEFAULT_BASELINE_M = 0.075
DEFAULT_DEPTH_SCALE = 1000.0
INTRINSICS_NAMES = ("camera_intrinsic.json", "intrinsic.json", "intrinsics.json", "camera.json")
COLOR_NAMES = ("color", "rgb", "image", "left")
_IMAGE_EXT = {".png", ".jpg", ".jpeg"}


@dataclass(frozen=True)
class DepthFolderConfig:
    """A folder of depth PNGs; the options override the intrinsics JSON (metadata: spelling, bounds, help)."""

    path: Path = option(target=True, key="path", example="captures/desk", help="the folder of depth PNGs and the intrinsics JSON")
    baseline_m: float | None = option(None, key="baseline", min=0.0, min_open=True, unit="m",
                                      default_text="the JSON's, else 0.075", help="baseline the disparity is expressed with")
    depth_scale: float | None = option(None, min=0.0, min_open=True, unit="PNG units per m",
                                       default_text="the JSON's, else 1000 (mm)", help="depth PNG units per metre")
    fps: float | None = option(None, min=0.0, min_open=True, unit="frames/s", default_text="the JSON's", help="frame rate")
    loop: bool = option(False, help="start again at the end")

    def __post_init__(self) -> None:
        check_options(self, SourceError, "depthpng option ")


@dataclass(frozen=True)
class DepthIntrinsics:
    camera: PinholeCamera
    depth_scale: float
    baseline_m: float
    doffs: float
    fps: float


def _find_intrinsics(folder: Path) -> Path:
    for name in INTRINSICS_NAMES:
        if (folder / name).is_file():
            return folder / name
    found = sorted(folder.glob("*.json"))
    if len(found) == 1:
        return found[0]
    if not found:
        raise CalibrationError(
            f"{folder} has no intrinsics JSON; add camera_intrinsic.json with width, height and "
            "intrinsic_matrix (Open3D) or fx, fy, cx, cy"
        )
    raise CalibrationError(f"{folder} has several JSON files ({', '.join(p.name for p in found)}); name the intrinsics camera_intrinsic.json")


def _number(obj: dict[str, Any], path: Path, *keys: str) -> float | None:
    for k in keys:
        if k in obj:
            try:
                return float(obj[k])
            except (TypeError, ValueError) as exc:
                raise CalibrationError(f"{path}: {k}={obj[k]!r} is not a number") from exc
    return None


def read_intrinsics(path: Path, width: int, height: int) -> DepthIntrinsics:
    """Parse an Open3D-style or flat intrinsics JSON; width/height default to the depth image's size."""
    try:
        obj = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{path} cannot be read as JSON ({exc}); fix or replace the intrinsics file") from exc
    if not isinstance(obj, dict):
        raise CalibrationError(f"{path} must hold a JSON object with the camera intrinsics")
    if "intrinsic_matrix" in obj:
        m = np.asarray(obj["intrinsic_matrix"], dtype=np.float64).ravel()
        if m.size != 9:
            raise CalibrationError(f"{path}: intrinsic_matrix must have 9 numbers, got {m.size}")
        nested = np.ndim(obj["intrinsic_matrix"]) == 2
        # Open3D writes the flat matrix column-major ([fx,0,0, 0,fy,0, cx,cy,1]); a nested 3x3 is row-major.
        k = m.reshape(3, 3) if nested or (m[2] != 0 and m[6] == 0) else m.reshape(3, 3).T
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    else:
        fx, fy = _number(obj, path, "fx"), _number(obj, path, "fy")
        cx, cy = _number(obj, path, "cx", "ppx"), _number(obj, path, "cy", "ppy")
        if None in (fx, fy, cx, cy):
            raise CalibrationError(f"{path} needs intrinsic_matrix (Open3D) or fx, fy, cx, cy")
    w = int(_number(obj, path, "width") or width)
    h = int(_number(obj, path, "height") or height)
    if (w, h) != (width, height):
        raise CalibrationError(f"{path} describes a {w}x{h} camera but the depth images are {width}x{height}; use the matching intrinsics")
    try:
        camera = PinholeCamera(fx=float(fx), fy=float(fy), cx=float(cx), cy=float(cy), width=w, height=h)
    except MeasureError as exc:
        raise CalibrationError(f"{path}: {exc}") from exc
    scale = _number(obj, path, "depth_scale")
    baseline = _number(obj, path, "baseline_m")
    doffs = _number(obj, path, "doffs")
    fps = _number(obj, path, "fps")
    return DepthIntrinsics(
        camera=camera,
        depth_scale=DEFAULT_DEPTH_SCALE if scale is None else scale,
        baseline_m=DEFAULT_BASELINE_M if baseline is None else baseline,
        doffs=0.0 if doffs is None else doffs,
        fps=0.0 if fps is None else fps,
    )


def _images(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in _IMAGE_EXT and p.is_file())


def find_pairs(folder: Path) -> tuple[list[Path], list[Path] | None]:
    """Depth PNGs and their colour images (None when there are none), paired in sorted order."""
    if (folder / "depth").is_dir():
        depth = [p for p in _images(folder / "depth") if p.suffix.lower() == ".png"]
        color = next((_images(folder / n) for n in COLOR_NAMES if (folder / n).is_dir()), None)
    else:
        files = _images(folder)
        depth = [p for p in files if p.name.lower().startswith("depth") and p.suffix.lower() == ".png"]
        color = None
        for prefix in COLOR_NAMES:
            match = [p for p in files if p.name.lower().startswith(prefix)]
            if match:
                color = match
                break
    if not depth:
        raise SourceNotFound(f"{folder} has no depth PNGs; expected depth/*.png or depth*.png (16-bit, PNG units per depth_scale)")
    if color is not None and len(color) != len(depth):
        raise RecordingError(
            f"{folder} has {len(depth)} depth and {len(color)} colour images; they pair up in file-name order, so remove the unmatched ones"
        )
    return depth, color or None


def depth_to_disparity(depth_m: np.ndarray, fx: float, baseline_m: float, doffs: float = 0.0) -> np.ndarray:
    """Metres (0 or NaN = none) -> float32 disparity px, NaN where no depth: d = fx * B / Z - doffs."""
    z = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(z) & (z > 0)
    d = np.full(z.shape, np.nan, dtype=np.float64)
    d[valid] = fx * baseline_m / z[valid] - doffs
    return d.astype(np.float32)


def _visualise(depth_m: np.ndarray) -> np.ndarray:
    valid = depth_m > 0
    out = np.zeros(depth_m.shape, np.uint8)
    if valid.any():
        inv = np.zeros(depth_m.shape)
        inv[valid] = 1.0 / depth_m[valid]
        lo, hi = inv[valid].min(), inv[valid].max()
        out[valid] = np.clip(40 + 215 * (inv[valid] - lo) / max(hi - lo, 1e-12), 0, 255).astype(np.uint8)
    return np.repeat(out[:, :, None], 3, axis=2)


class DepthFolderSource(SourceBase):
    """Frames from a depth-PNG folder, in file-name order; EndOfRecording at the end unless looping."""

    def __init__(self, config: DepthFolderConfig | str | Path) -> None:
        self.config = config if isinstance(config, DepthFolderConfig) else DepthFolderConfig(path=Path(config))
        self.info = SourceInfo(kind="depthpng", name=Path(self.config.path).name)
        self._depth: list[Path] = []
        self._color: list[Path] | None = None
        self._intr: DepthIntrinsics | None = None
        self._pos = 0

    def open(self) -> None:
        import cv2

        folder = Path(self.config.path)
        if not folder.is_dir():
            raise SourceNotFound(f"{folder} is not a folder; give depthpng:DIR with depth PNGs and an intrinsics JSON")
        depth, color = find_pairs(folder)
        first = self._read_depth_png(depth[0], cv2)
        intr = read_intrinsics(_find_intrinsics(folder), first.shape[1], first.shape[0])
        overrides = {k: v for k, v in (("baseline_m", self.config.baseline_m), ("depth_scale", self.config.depth_scale), ("fps", self.config.fps)) if v is not None}
        intr = DepthIntrinsics(**{**intr.__dict__, **overrides})
        if not intr.baseline_m > 0 or not intr.depth_scale > 0:
            raise CalibrationError(f"baseline_m={intr.baseline_m} and depth_scale={intr.depth_scale} must be positive")
        self._depth, self._color, self._intr, self._pos = depth, color, intr, 0
        self.info = SourceInfo(
            kind="depthpng",
            name=folder.name,
            width=intr.camera.width,
            height=intr.camera.height,
            fps=intr.fps,
            extra={"path": str(folder), "frames": len(depth), "baseline_m": intr.baseline_m, "depth_scale": intr.depth_scale},
        )
        super().open()

    @staticmethod
    def _read_depth_png(path: Path, cv2: Any) -> np.ndarray:
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise RecordingError(f"{path} is missing or corrupt and cannot be decoded; replace or remove it")
        if img.ndim != 2 or img.dtype != np.uint16:
            raise RecordingError(f"{path} is {img.dtype} with shape {img.shape}; a depth PNG must be single-channel 16-bit")
        return img

    def read(self, timeout_s: float = 1.0) -> Frame:
        import cv2

        intr = self._intr
        if intr is None or not self.is_open:
            raise SourceError("the depth-folder source is not open; call open() or use it in a with block")
        if self._pos >= len(self._depth):
            if not self.config.loop:
                raise EndOfRecording(f"{self.config.path}: all {len(self._depth)} depth images were read; use depthpng:DIR?loop=1 to repeat")
            self._pos = 0
        i = self._pos
        self._pos += 1
        cam = intr.camera
        raw = self._read_depth_png(self._depth[i], cv2)
        if raw.shape != (cam.height, cam.width):
            raise RecordingError(f"{self._depth[i]} is {raw.shape[1]}x{raw.shape[0]}, the others {cam.width}x{cam.height}; all depth images must match")
        depth_m = raw.astype(np.float64) / intr.depth_scale
        meta: dict[str, Any] = {"source": "depthpng", "file": self._depth[i].name, "frame_index": i}
        if self._color is not None:
            image = cv2.imread(str(self._color[i]), cv2.IMREAD_COLOR)
            if image is None:
                raise RecordingError(f"{self._color[i]} is missing or corrupt and cannot be decoded; replace or remove it")
            if image.shape[:2] != raw.shape:
                raise RecordingError(
                    f"{self._color[i]} is {image.shape[1]}x{image.shape[0]} but its depth image is {cam.width}x{cam.height}; "
                    "export depth registered to colour at the colour resolution"
                )
        else:
            image = _visualise(depth_m)
            meta["image"] = "depth-visualisation"
        return Frame(
            image=image,
            disparity=depth_to_disparity(depth_m, cam.fx, intr.baseline_m, intr.doffs),
            camera=cam,
            baseline_m=intr.baseline_m,
            doffs=intr.doffs,
            timestamp=i / intr.fps if intr.fps > 0 else 0.0,
            meta=meta,
        )

    def close(self) -> None:
        self._intr = None
        super().close()


def config_from_spec(spec: SourceSpec) -> DepthFolderConfig:
    """DepthFolderConfig from ``depthpng:DIR?baseline=0.075&depth_scale=1000&fps=30&loop=1`` (device.configs)."""
    return configs.from_spec(DepthFolderConfig, spec, SourceNotFound("depthpng needs a folder: depthpng:path/to/folder"))


__all__ = ["DEFAULT_BASELINE_M", "DepthFolderConfig", "DepthFolderSource", "config_from_spec", "depth_to_disparity", "read_intrinsics"]
