"""Middlebury 2014 stereo scenes (im0/im1, calib.txt, disp0GT.pfm, mask0nocc.png) as frames.

Source spec: ``middlebury:PATH?disparity=sgbm|gt|gt-int``. ``sgbm`` (default) runs OpenCV SGBM on
the pair; ``gt`` uses the ground truth; ``gt-int`` the ground truth rounded to whole pixels.
Every frame carries the ground truth in ``meta["gt_disparity"]``.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from measure import Frame, PinholeCamera, check_options, option

from device import configs
from device.base import SourceBase, SourceInfo, SourceSpec
from device.errors import CalibrationError, SourceError, SourceNotFound
from device.sources.sgbm import SGBMConfig, compute_disparity, round_up_disparities


@dataclass(frozen=True)
class MiddleburyScene:
    name: str
    left: np.ndarray  # H x W x 3 uint8 BGR
    right: np.ndarray
    camera: PinholeCamera
    baseline_m: float
    doffs: float
    gt_disparity: np.ndarray  # float32 px, NaN unknown
    nonocc_mask: np.ndarray  # bool, non-occluded with ground truth
    ndisp: int


def read_pfm(path: str | Path) -> np.ndarray:
    """A single-channel PFM as float32, top row first; ``inf`` (unknown) becomes NaN.

    cv2.imread scales PFM by 255, so parse it here.
    """
    path = Path(path)
    with path.open("rb") as f:
        header = f.readline().strip()
        if header != b"Pf":
            raise CalibrationError(f"{path}: expected a greyscale PFM ('Pf' header), got {header[:8]!r}")
        dims = f.readline().split()
        while len(dims) < 2:
            dims += f.readline().split()
        width, height = int(dims[0]), int(dims[1])
        scale = float(f.readline().strip())
        payload = f.read()
    if len(payload) != 4 * width * height:
        raise CalibrationError(
            f"{path}: PFM holds {len(payload)} bytes, header says {width}x{height} floats; the file is truncated"
        )
    data = np.frombuffer(payload, dtype="<f4" if scale < 0 else ">f4")
    img = np.flipud(data.reshape(height, width)).astype(np.float32)
    img[~np.isfinite(img)] = np.nan
    return img


def read_calib(path: str | Path) -> dict[str, object]:
    """calib.txt as a dict: cam0/cam1 as 3x3 arrays, numbers as floats. Whitespace is irregular."""
    path = Path(path)
    out: dict[str, object] = {}
    for line in path.read_text().splitlines():
        if "=" not in line:
            continue
        key, _, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if value.startswith("["):
            nums = [float(v) for v in re.split(r"[\s;\[\]]+", value) if v]
            out[key] = np.array(nums, dtype=np.float64).reshape(3, 3)
        else:
            out[key] = float(value)
    missing = {"cam0", "doffs", "baseline"} - out.keys()
    if missing:
        raise CalibrationError(f"{path}: missing {', '.join(sorted(missing))}; is this a Middlebury calib.txt?")
    return out


def load_scene(path: str | Path) -> MiddleburyScene:
    import cv2

    path = Path(path)
    if not (path / "im0.png").is_file():
        raise SourceNotFound(f"{path} is not a Middlebury scene folder (no im0.png); point at a folder with im0.png, im1.png, calib.txt")
    calib = read_calib(path / "calib.txt")
    left = cv2.imread(str(path / "im0.png"), cv2.IMREAD_COLOR)
    right = cv2.imread(str(path / "im1.png"), cv2.IMREAD_COLOR)
    if left is None or right is None:
        raise SourceNotFound(f"{path}: im0.png or im1.png cannot be decoded")
    h, w = left.shape[:2]
    k = calib["cam0"]
    camera = PinholeCamera(fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], width=w, height=h)
    gt_path = path / "disp0GT.pfm"
    gt = read_pfm(gt_path) if gt_path.is_file() else np.full((h, w), np.nan, np.float32)
    mask_path = path / "mask0nocc.png"
    mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE) if mask_path.is_file() else None
    nonocc = (mask == 255) if mask is not None else np.isfinite(gt)
    return MiddleburyScene(
        name=path.name,
        left=left,
        right=right,
        camera=camera,
        baseline_m=float(calib["baseline"]) / 1000.0,
        doffs=float(calib["doffs"]),
        gt_disparity=gt,
        nonocc_mask=nonocc & np.isfinite(gt),
        ndisp=int(calib.get("ndisp", 128)),
    )


def scene_sgbm_config(scene: MiddleburyScene, **overrides) -> SGBMConfig:
    """SGBM settings for a scene: its disparity range from calib ``ndisp``, the rest default."""
    return SGBMConfig(num_disparities=round_up_disparities(scene.ndisp), **overrides)


def scene_frame(scene: MiddleburyScene, disparity: np.ndarray, confidence: np.ndarray | None = None) -> Frame:
    return Frame(
        image=scene.left,
        disparity=np.ascontiguousarray(disparity, dtype=np.float32),
        camera=scene.camera,
        baseline_m=scene.baseline_m,
        doffs=scene.doffs,
        confidence=confidence,
        meta={"source": "middlebury", "scene": scene.name, "gt_disparity": scene.gt_disparity},
    )


DISPARITY_KINDS = ("sgbm", "gt", "gt-int")


@dataclass(frozen=True)
class MiddleburyConfig:
    """One Middlebury scene: each field's spelling, choices and help are in its metadata."""

    path: Path = option(target=True, key="path", example="data/middlebury/Teddy", help="a scene folder (im0.png, im1.png, calib.txt, disp0.pfm)")
    disparity: str = option("sgbm", choices=DISPARITY_KINDS,
                            help="sgbm: computed from the pair; gt: the ground truth; gt-int: the ground truth rounded")

    def __post_init__(self) -> None:
        check_options(self, SourceError, "middlebury option ")


class MiddleburySource(SourceBase):
    """One Middlebury scene as a still source: every read returns the same frame."""

    def __init__(self, config: MiddleburyConfig | str | Path, disparity: str = "sgbm") -> None:
        self.config = config if isinstance(config, MiddleburyConfig) else MiddleburyConfig(Path(config), disparity)
        self.path = Path(self.config.path)
        self.disparity_kind = self.config.disparity
        self.info = SourceInfo(kind="middlebury", name=self.path.name)
        self._frame: Frame | None = None

    def open(self) -> None:
        scene = load_scene(self.path)
        if self.disparity_kind == "sgbm":
            disp, conf = compute_disparity(scene.left, scene.right, scene_sgbm_config(scene))
        else:
            disp = scene.gt_disparity if self.disparity_kind == "gt" else np.round(scene.gt_disparity)
            conf = None
        self._frame = scene_frame(scene, disp, conf)
        h, w = disp.shape
        self.info = SourceInfo(kind="middlebury", name=scene.name, width=w, height=h)
        super().open()

    def read(self, timeout_s: float = 1.0) -> Frame:
        if self._frame is None:
            raise SourceError("the Middlebury source is not open; call open() or use it in a with block")
        return Frame(**{**self._frame.__dict__, "timestamp": time.time()})


def config_from_spec(spec: SourceSpec) -> MiddleburyConfig:
    """MiddleburyConfig from ``middlebury:path/to/Teddy?disparity=gt`` (device.configs)."""
    return configs.from_spec(MiddleburyConfig, spec, SourceNotFound("middlebury needs a scene folder: middlebury:path/to/Adirondack"))
