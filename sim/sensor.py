"""Sensor model of the paper's three-camera rig (a Dell Venue 8 with RealSense Snapshot, docs/method.md "Results to beat").

The rig: one high-resolution reference (colour) camera and two lower-resolution auxiliary cameras,
each forming a stereo pair with it: the *wide* pair (``baseline_wide_m``, aux camera to the right)
and the *narrow* pair (``baseline_narrow_m``, to the left); plausible tablet baselines, not published
figures. Disparity is registered to the reference camera and expressed for the wide pair: a frame's
``baseline_m`` is ``baseline_wide_m``, ``doffs`` is 0, ``Z = fx * baseline_wide_m / d`` (px, m).

Effects (``sense``), each a field of :class:`SensorModel` (0 / False = off):

- Per pixel one pair's estimate: the wide pair's unless its aux camera cannot see the point and the
  narrow one can; occluded for both = hole. Random effects come in ``aux_block`` px blocks.
- Gaussian noise ``noise_px`` (wide-pair px; the narrow pair's larger by the baseline ratio), per
  aux pixel or, with ``noise_window_px``, averaged over a matching window (spatially correlated);
  plus ``calibration_px``, a one-sigma offset common to the whole frame.
- Pair contention: in contended regions (``contention_at="edges"``: within ``contention_band_px``
  of a depth edge; ``"disagreement"``: of a strip one aux camera sees and the other does not; blobs
  over ``contention_low_texture`` / ``contention_area`` of the low-texture / textured area) a share
  ``contention`` of the pixels carries the wrong pair's match: ``outlier_model="mismatch"`` moves it
  by ``mismatch_min_px``..``mismatch_max_px`` either way, ``"baseline"`` converts the other pair's
  disparity with the wrong baseline, ``"other-surface"`` takes the surface's across the nearest edge.
  ``static_contention`` repeats these outliers frame after frame (``static_seed``).
- Edge fattening: foreground disparity bleeds ``edge_fattening_px`` into the background along rows,
  ``edge_fattening_vertical_px`` (default half of it) along columns. A depth edge is a step of more
  than ``edge_jump_px`` between neighbouring pixels' true disparity, or surface next to nothing.
- Holes (NaN): ``hole_fraction`` of low-texture pixels (blocks of ``hole_block_px``), occlusions, and
  ``stray_hole_fraction`` everywhere; ``stray_outlier_fraction`` of random disparities everywhere.
- Quantization of the output to multiples of ``quantization`` px (1 = integer, 0 = none), and an
  optional confidence map, lower in contended and low-texture regions and lower still on outliers.

``noise_px`` and ``hole_fraction`` default to the lighting preset's values (sim.textures.LIGHTING).
``PROFILES`` (``sim:...?profile=paper``, ``depthruler eval sim --profile paper``): ``stress`` (the
default: the field defaults above, the poster on a stand, taps aimed at the boundary pixel with a
quarter of them up to 6 px beyond it) and ``paper`` (the tablet as the paper describes it; each
choice and its evidence: docs/decisions/paper-profile.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from sim.scenes import View
from sim.textures import LIGHTING, noise_tile
from sim.truth import ClickModel

OUTLIER_MODELS = ("mismatch", "baseline", "other-surface")
CONTENTION_AT = ("edges", "disagreement")


@dataclass(frozen=True)
class Profile:
    """A named regime of the simulated rig: SensorModel field values, how people click, the poster's mount."""

    name: str
    sensor: tuple[tuple[str, object], ...]  # SensorModel fields that differ from the defaults
    clicks: ClickModel
    mount: str  # "stand" | "wall" (sim.scenes.MOUNTS)


PROFILES: dict[str, Profile] = {
    "stress": Profile("stress", (), ClickModel(), "stand"),
    "paper": Profile(
        "paper",
        (
            ("quantization", 1.0),
            ("noise_window_px", 9),
            ("edge_fattening_px", 4),
            ("edge_fattening_vertical_px", 4),
            ("contention_at", "disagreement"),
            ("contention_band_px", 4),
            ("contention_area", 0.0),
            ("contention_low_texture", 0.0),
            ("outlier_model", "other-surface"),
            ("calibration_px", 0.3),
        ),
        ClickModel(off_object_prob=0.0),
        "wall",
    ),
}


def get_profile(name: str) -> Profile:
    """The profile called ``name``; SensorError naming the known ones otherwise."""
    try:
        return PROFILES[name]
    except KeyError:
        raise SensorError(f"profile={name!r} is unknown; use one of {', '.join(PROFILES)}") from None


class SensorError(ValueError):
    """A sensor parameter is out of range; the message names it and the allowed values."""


@dataclass(frozen=True)
class SensorModel:
    """Every effect of the simulated rig, with its default (see the module docstring)."""

    lighting: str = "indoor"  # preset of noise_px / hole_fraction / image contrast: indoor | mixed | outdoor
    baseline_wide_m: float = 0.06  # wide pair (reference + aux camera to its right); the frame's baseline
    baseline_narrow_m: float = 0.015  # narrow pair (reference + aux camera to its left)
    aux_block: int = 2  # reference pixels per aux-camera pixel (aux cameras at half resolution)
    quantization: float = 0.25  # output disparity step (px); 1 = integer disparity, 0 = none
    contention: float = 0.5  # share of contended pixels carrying the wrong pair's match (outliers)
    contention_band_px: int = 12  # contended band around depth discontinuities (px)
    contention_area: float = 0.15  # share of the textured area contended (in blobs)
    contention_low_texture: float = 0.5  # share of the low-texture area contended (in blobs)
    low_texture_std: float = 3.0  # grey-level std (in texture_window_px) below which texture is "low"
    texture_window_px: int = 9  # window of that local std (px)
    outlier_model: str = "mismatch"  # "mismatch": +-[min, max] px; "baseline": wrong baseline; "other-surface": across the edge
    mismatch_min_px: float = 2.0  # smallest wrong-match offset (px)
    mismatch_max_px: float = 8.0  # largest wrong-match offset (px)
    edge_fattening_px: int = 3  # foreground bleeds this far (px) into the background at depth edges
    edge_fattening_vertical_px: int | None = None  # the same across horizontal edges; None = half of edge_fattening_px
    contention_at: str = "edges"  # "edges": band around every depth edge; "disagreement": where one aux camera is occluded
    noise_window_px: int = 0  # disparity noise is the mean over this matching window (px): spatially correlated; 0 = per aux pixel
    calibration_px: float = 0.0  # one-sigma disparity offset common to a whole frame (px): calibration error
    edge_jump_px: float = 0.5  # a disparity step (px) between neighbouring pixels this large is a depth edge
    noise_px: float | None = None  # Gaussian disparity noise sigma (px); None = the lighting preset's
    hole_fraction: float | None = None  # share of low-texture pixels without data; None = the preset's
    hole_block_px: int = 4  # holes come in blocks of this size (px)
    stray_hole_fraction: float = 0.002  # holes anywhere
    stray_outlier_fraction: float = 0.002  # uniformly random disparities anywhere
    occlusion_holes: bool = True  # pixels neither aux camera sees are holes
    min_disparity_px: float = 0.25  # smaller disparities (beyond range) are holes
    confidence: bool = True  # also produce a confidence map
    static_contention: bool = False  # the contention outliers (which pixels, how far) repeat in every frame
    static_seed: int = 0  # the seed of that fixed pattern (a still scene under one light keeps its wrong matches)

    def __post_init__(self) -> None:
        if self.lighting not in LIGHTING:
            raise SensorError(f"lighting={self.lighting!r} is unknown; use one of {', '.join(LIGHTING)}")
        if self.contention_at not in CONTENTION_AT:
            raise SensorError(f"contention_at={self.contention_at!r} is unknown; use one of {', '.join(CONTENTION_AT)}")
        if self.outlier_model not in OUTLIER_MODELS:
            raise SensorError(f"outlier_model={self.outlier_model!r} is unknown; use one of {', '.join(OUTLIER_MODELS)}")
        for name in ("contention", "contention_area", "contention_low_texture", "stray_hole_fraction", "stray_outlier_fraction"):
            if not (0.0 <= getattr(self, name) <= 1.0):
                raise SensorError(f"{name}={getattr(self, name)} must lie in [0, 1]")
        if self.hole_fraction is not None and not (0.0 <= self.hole_fraction <= 1.0):
            raise SensorError(f"hole_fraction={self.hole_fraction} must lie in [0, 1]")
        if not (self.baseline_wide_m > 0 and self.baseline_narrow_m > 0):
            raise SensorError("baseline_wide_m and baseline_narrow_m must be positive (metres)")
        if not self.edge_jump_px > 0:
            raise SensorError(f"edge_jump_px={self.edge_jump_px} must be > 0 (pixels of disparity)")
        if self.quantization < 0 or (self.noise_px is not None and self.noise_px < 0):
            raise SensorError("quantization and noise_px must be >= 0 (pixels)")
        if not (0 <= self.mismatch_min_px <= self.mismatch_max_px):
            raise SensorError("need 0 <= mismatch_min_px <= mismatch_max_px (pixels)")
        for name in ("aux_block", "hole_block_px", "texture_window_px"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise SensorError(f"{name}={getattr(self, name)} must be a positive whole number of pixels")
        for name in ("contention_band_px", "edge_fattening_px", "noise_window_px") + (
            ("edge_fattening_vertical_px",) if self.edge_fattening_vertical_px is not None else ()
        ):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 0:
                raise SensorError(f"{name}={getattr(self, name)} must be a whole number of pixels >= 0")

    @property
    def effective_noise_px(self) -> float:
        return LIGHTING[self.lighting].noise_px if self.noise_px is None else self.noise_px

    @property
    def effective_hole_fraction(self) -> float:
        return LIGHTING[self.lighting].hole_fraction if self.hole_fraction is None else self.hole_fraction

    def static_key(self) -> SensorModel:
        """The model with the per-frame-only fields reset: what the cached static maps depend on."""
        return replace(self, contention=0.0, noise_px=0.0, hole_fraction=0.0, quantization=0.0,
                       stray_hole_fraction=0.0, stray_outlier_fraction=0.0, mismatch_min_px=0.0,
                       mismatch_max_px=0.0, outlier_model="mismatch", noise_window_px=0, calibration_px=0.0,
                       confidence=False, static_contention=False, static_seed=0)


@dataclass(frozen=True)
class StaticMaps:
    """Per (scene view, lighting, static sensor fields): everything that does not change frame to frame."""

    d_true: np.ndarray  # true wide-pair disparity (px), NaN where no surface
    d_fat: np.ndarray  # after edge fattening
    contended: np.ndarray  # bool
    low_texture: np.ndarray  # bool
    use_narrow: np.ndarray  # bool: the wide aux camera is occluded there, the narrow one is not
    occluded: np.ndarray  # bool: both aux cameras are occluded (a hole)
    conf_base: np.ndarray  # float16 base confidence (half the memory of float32; it is a coarse prior)
    narrow_idx: np.ndarray  # flat indices of use_narrow
    d_max: float  # largest true disparity (px), the range of stray outliers
    d_other: np.ndarray  # true disparity of the other surface across the nearest edge (= d_true away from edges)


@dataclass(frozen=True)
class SensorOutput:
    """One simulated disparity map with what went into it (the masks are for tests and evaluation)."""

    disparity: np.ndarray  # H x W float32, NaN = hole
    confidence: np.ndarray | None
    outlier: np.ndarray  # bool: carries the wrong pair's match (contention)
    stray: np.ndarray  # bool: stray outlier
    static: StaticMaps
    offset_px: float = 0.0  # the disparity offset drawn for the whole frame (px): its calibration error


def _occluded(d: np.ndarray, direction: int, max_shift: int) -> np.ndarray:
    """Pixels whose point is hidden from an aux camera on side ``direction`` (+1 right, -1 left).

    A point at column x with disparity d(x) lands at x - direction*d(x) in the aux image; a pixel
    s columns towards that camera hides it if d(x + direction*s) - d(x) >= s.
    """
    occ = np.zeros(d.shape, bool)
    dd = np.where(np.isfinite(d), d, -1e6)  # finite, so that two empty pixels differ by 0, not NaN
    w = d.shape[1]
    for s in range(1, min(max_shift, w - 1) + 1):
        if direction > 0:
            occ[:, : w - s] |= dd[:, s:] - dd[:, : w - s] >= s
        else:
            occ[:, s:] |= dd[:, : w - s] - dd[:, s:] >= s
    return occ


def _share(field_: np.ndarray, where: np.ndarray, share: float) -> np.ndarray:
    """The ``share`` of ``where`` with the highest values of ``field_`` (blobs when the field is smooth)."""
    if share <= 0 or not where.any():
        return np.zeros(where.shape, bool)
    return where & (field_ >= np.quantile(field_[where], 1.0 - share))


def _box_std(gray: np.ndarray, k: int) -> np.ndarray:
    import cv2

    m = cv2.blur(gray, (k, k))
    m2 = cv2.blur(gray * gray, (k, k))
    return np.sqrt(np.maximum(m2 - m * m, 0.0))


@dataclass(frozen=True)
class _Geometry:
    d_true: np.ndarray
    d_fat: np.ndarray
    band: np.ndarray
    use_narrow: np.ndarray
    occluded: np.ndarray
    narrow_idx: np.ndarray
    d_max: float
    d_other: np.ndarray


@lru_cache(maxsize=48)  # per (scene, pose, size): ~9 MB each at 1280x720
def _geometry_maps(view: View, baseline_wide_m: float, baseline_narrow_m: float, fattening_px: int,
                   fattening_v_px: int, band_px: int, occlusion_holes: bool, jump_px: float,
                   contention_at: str) -> _Geometry:
    """The lighting-independent static maps: true and fattened disparity, contended band, occlusions,
    and the other surface's disparity across the nearest depth edge."""
    import cv2

    cam = view.camera
    h, w = view.depth.shape
    with np.errstate(divide="ignore", invalid="ignore"):
        d_true = (cam.fx * baseline_wide_m / view.depth).astype(np.float32)
    valid = np.isfinite(d_true)
    d0 = np.where(valid, d_true, 0.0).astype(np.float32)
    k = fattening_px
    if k:
        # Block matching assigns a window straddling an edge the foreground's disparity: horizontally
        # (along the epipolar line) by k px, vertically by fattening_v_px.
        kernel = np.ones((2 * fattening_v_px + 1, 2 * k + 1), np.uint8)
        dil = cv2.dilate(d0, kernel)
        d_fat = np.where(valid & (dil - d0 > jump_px), dil, d_true).astype(np.float32)
    else:
        d_fat = d_true.copy()
    jump = np.zeros((h, w), bool)
    jump[:, 1:] |= ~(np.abs(d0[:, 1:] - d0[:, :-1]) <= jump_px) | (valid[:, 1:] != valid[:, :-1])
    jump[1:, :] |= ~(np.abs(d0[1:, :] - d0[:-1, :]) <= jump_px) | (valid[1:, :] != valid[:-1, :])
    span = int(math.ceil(np.nanmax(d_true) - np.nanmin(d_true))) + 1 if valid.any() else 0
    ratio = baseline_narrow_m / baseline_wide_m
    occ_wide = _occluded(d_fat, +1, span)
    occ_narrow = _occluded(d_fat * ratio, -1, int(math.ceil(span * ratio)) + 1)
    use_narrow = occ_wide & ~occ_narrow & valid
    occluded = occ_wide & occ_narrow & valid if occlusion_holes else np.zeros((h, w), bool)
    # Where the contention is: around every depth edge, or only where the two pairs see different
    # things (one aux camera occluded, the other not), widened by the band (a window touching the strip).
    seed_ = jump if contention_at == "edges" else (occ_wide != occ_narrow) & valid
    b = band_px
    square = np.ones((2 * b + 1, 2 * b + 1), np.uint8)
    band = cv2.dilate(seed_.astype(np.uint8), square).astype(bool) if b else seed_.copy()
    band &= valid
    # The other surface across the nearest edge within the band: the nearer one for a background
    # pixel, the farther one for a foreground pixel (what the pair that cannot see the point matches).
    far = np.where(valid, d_true, np.float32(1e6)).astype(np.float32)
    d_near = cv2.dilate(d0, square) if b else d0
    d_far = cv2.erode(far, square) if b else d0
    d_far = np.where(d_far >= 1e6, d0, d_far)
    d_other = np.where(d_near - d_fat > d_fat - d_far, d_near, d_far).astype(np.float32)
    d_max = float(np.nanmax(d_true)) if valid.any() else 1.0
    for a in (d_true, d_fat, band, use_narrow, occluded, d_other):
        a.setflags(write=False)
    return _Geometry(d_true, d_fat, band, use_narrow, occluded, np.flatnonzero(use_narrow), d_max, d_other)


@lru_cache(maxsize=160)  # (scene, pose, size) x lighting: ~4 MB each at 1280x720 (+ the shared geometry)
def static_maps(view: View, model: SensorModel) -> StaticMaps:
    """The cached static part of the sensor model for one view (``model`` should be ``static_key()``)."""
    import cv2

    fat_v = model.edge_fattening_px // 2 if model.edge_fattening_vertical_px is None else model.edge_fattening_vertical_px
    geo = _geometry_maps(view, model.baseline_wide_m, model.baseline_narrow_m, model.edge_fattening_px, fat_v,
                         model.contention_band_px, model.occlusion_holes, model.edge_jump_px, model.contention_at)
    h, w = view.depth.shape
    valid = np.isfinite(geo.d_true)
    gray = cv2.cvtColor(view.renders[model.lighting], cv2.COLOR_BGR2GRAY).astype(np.float32)
    low = (_box_std(gray, model.texture_window_px) < model.low_texture_std) & valid
    # Contention away from edges comes in blobs (repetitive texture, specular patches): fixed smooth
    # fields thresholded to the requested share of the textured area and of the low-texture area.
    fields_ = cv2.resize(np.ascontiguousarray(noise_tile(12345, 256)[:128, :]), (w, h * 2), interpolation=cv2.INTER_LINEAR)
    blob = _share(fields_[:h], valid & ~low, model.contention_area)
    blob_low = _share(fields_[h:], low, model.contention_low_texture)
    contended = geo.band | ((blob | blob_low) & valid)
    conf_base = (0.95 - 0.30 * contended - 0.25 * low - 0.15 * geo.use_narrow).astype(np.float16)
    for a in (contended, low, conf_base):
        a.setflags(write=False)
    return StaticMaps(geo.d_true, geo.d_fat, contended, low, geo.use_narrow, geo.occluded, conf_base,
                      geo.narrow_idx, geo.d_max, geo.d_other)


def clear_static_maps() -> None:
    """Empty the caches of static maps: a study whose every frame is a new view (``sim.shapes``) only
    fills them (about 100 MB per 1280x720 view, up to several GB)."""
    static_maps.cache_clear()
    _geometry_maps.cache_clear()


def _blocks(a: np.ndarray, block: int, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour upsampling of a coarse field by ``block``, cropped to ``shape``."""
    import cv2

    if block == 1:
        return a[: shape[0], : shape[1]]
    hb, wb = a.shape
    src = a.view(np.uint8) if a.dtype == bool else a
    up = cv2.resize(src, (wb * block, hb * block), interpolation=cv2.INTER_NEAREST_EXACT)[: shape[0], : shape[1]]
    return up.view(bool) if a.dtype == bool else up


def sense(view: View, model: SensorModel, rng: np.random.Generator) -> SensorOutput:
    """One disparity map (and confidence) of ``view`` as the rig would deliver it; see the module docstring.

    Every random decision is drawn at the auxiliary cameras' resolution and only then spread over the
    reference pixels, which is both what the rig does and what keeps a 1280x720 frame cheap.
    """
    st = static_maps(view, model.static_key())
    shape = st.d_true.shape
    h, w = shape
    b = model.aux_block
    hb, wb = -(-h // b), -(-w // b)
    u = rng.random((5, hb, wb), dtype=np.float32)
    if model.static_contention:
        # Which pixels carry a wrong match and how far it is off: the same in every frame of the scene.
        u[:3] = np.random.default_rng([model.static_seed, 0x5EED]).random((3, hb, wb), dtype=np.float32)
    ratio = np.float32(model.baseline_wide_m / model.baseline_narrow_m)
    noise = rng.standard_normal((hb, wb), dtype=np.float32)
    k = int(round(model.noise_window_px / b))
    if k > 1:
        import cv2

        # Neighbouring windows share most of their pixels: their errors are the mean of one field over
        # the window (a k x k box mean of unit noise has std 1/k; scale back to noise_px).
        noise = cv2.blur(noise, (k, k), borderType=cv2.BORDER_REFLECT) * np.float32(k)
    noise *= np.float32(model.effective_noise_px)
    offset = float(rng.normal(0.0, model.calibration_px)) if model.calibration_px > 0 else 0.0
    if offset:
        noise += np.float32(offset)
    d = _blocks(noise, b, shape)
    if st.narrow_idx.size:
        d.ravel()[st.narrow_idx] *= ratio
    d += st.d_fat
    outlier = st.contended & _blocks(u[0] < model.contention, b, shape)
    if model.outlier_model == "mismatch":
        mag = model.mismatch_min_px + (model.mismatch_max_px - model.mismatch_min_px) * u[1]
        np.add(d, _blocks(np.where(u[2] < 0.5, -mag, mag).astype(np.float32), b, shape), out=d, where=outlier)
    elif model.outlier_model == "baseline":
        wrong = np.where(st.use_narrow, d * ratio, d / ratio)
        np.copyto(d, wrong, where=outlier)
    else:  # other-surface: the match of the surface across the edge, with this pixel's noise
        np.add(d, st.d_other - st.d_fat, out=d, where=outlier)
    # Stray outliers are rare: place their blocks by index instead of upsampling a mask.
    cy, cx = np.nonzero(u[3] < model.stray_outlier_fraction)
    ys = (cy[:, None] * b + np.repeat(np.arange(b), b)[None, :]).ravel()
    xs = (cx[:, None] * b + np.tile(np.arange(b), b)[None, :]).ravel()
    keep = (ys < h) & (xs < w)
    ys, xs = ys[keep], xs[keep]
    keep = np.isfinite(st.d_true[ys, xs])  # where no surface is, nothing can be matched
    ys, xs = ys[keep], xs[keep]
    d[ys, xs] = u[1][ys // b, xs // b] * np.float32(st.d_max * 1.5)
    stray = np.zeros(shape, bool)
    stray[ys, xs] = True
    q = model.quantization
    if q > 0:
        d *= np.float32(1.0 / q)
        np.round(d, out=d)
        d *= np.float32(q)
    hb4, wb4 = -(-h // model.hole_block_px), -(-w // model.hole_block_px)
    uh = rng.random((2, hb4, wb4), dtype=np.float32)
    holes = st.low_texture & _blocks(uh[0] < model.effective_hole_fraction, model.hole_block_px, shape)
    holes |= _blocks(uh[1] < model.stray_hole_fraction, model.hole_block_px, shape)
    holes |= st.occluded
    holes |= ~(d >= model.min_disparity_px)
    np.copyto(d, np.float32(np.nan), where=holes)
    conf = None
    if model.confidence:
        c = _blocks(u[4], b, shape) * np.float32(0.4)
        c += st.conf_base
        c -= np.float32(0.2)
        c -= np.float32(0.35) * outlier
        c -= np.float32(0.5) * stray
        np.clip(c, 0.0, 1.0, out=c)
        # in 8-bit steps, as a device's confidence map (DepthAI's 0-255): the service's ring holds it in a byte
        c *= np.float32(255.0)
        np.rint(c, out=c)
        c /= np.float32(255.0)
        c[holes] = 0.0
        conf = c
    kept = ~holes
    return SensorOutput(d, conf, outlier & kept, stray & kept, st, offset)
