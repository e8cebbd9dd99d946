"""A frame held in the ring in the fewest bytes that give its arrays back bit for bit.

A quantized disparity (the simulator's 1/4 px, a DepthAI's 1/8 px, SGBM's 1/16 px: every step a power
of two no finer than 1/64 px, below 512 px) is held as codes of its own step: uint8 when they fit
below ``NAN_CODE_U8`` (NaN), else int16 codes ``round(d * 64)`` (NaN ``NAN_CODE``); an 8-bit
confidence (a device's 0-255 map, the simulator's) as uint8 codes ``round(c * 255)``. Each packing
is checked by unpacking it and comparing bit for bit: an array it does not give back exactly
(noise-free float disparity, a finer confidence) is held as it is. Codes are then compressed
losslessly (zstd at level ``ZSTD_LEVEL``) when that saves at least a quarter of their bytes. The
image of a frame whose source says how to make it again (``meta[REBUILD_IMAGE]``: the simulator's
render plus a crop of its noise sheet) is not held: it is made when asked for. Why: the ring holds
30 frames for several-frame measurements, and at 1280x720 a float32 disparity and confidence are
7.4 of a frame's 10.1 MB, the image 2.8; compressing the codes costs a few ms of the capture
thread per frame (docs/decisions/measure-pool.md).
"""

from __future__ import annotations

import mmap
import threading
import weakref
from collections.abc import Mapping
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zstandard

from device.base import REBUILD_IMAGE
from measure import Frame, PinholeCamera

DISPARITY_SCALE = np.float32(64.0)  # codes per pixel of disparity (1/64 px steps)
NAN_CODE = np.int16(-32768)
NAN_CODE_U8 = 255
CONFIDENCE_SCALE = np.float32(255.0)
_NAN_BITS = np.float32(np.nan).view(np.uint32)
ZSTD_LEVEL = 1  # the fastest of zstd's ordinary levels: 4-5x on the simulator's disparity codes, 2.5x on its confidence
KEEP_IF_AT_MOST = 0.75  # compressed codes are kept when they take at most this share of the raw codes' bytes
_CODECS = threading.local()  # a zstd context is for one thread at a time: one per thread that packs or unpacks


@dataclass(frozen=True, eq=False)
class Squeezed:
    """Integer codes (an H x W uint8 or int16 array) compressed with zstd: ``array()`` gives them back
    byte for byte. The compressed bytes live in a mapping of their own (``mmap``), not in malloc's
    arenas: a ring of them, each kept for seconds, would otherwise pin the arenas' memory between the
    frame-sized temporaries made and dropped around them (docs/decisions/measure-pool.md)."""

    data: mmap.mmap
    dtype: np.dtype
    shape: tuple[int, ...]

    @property
    def nbytes(self) -> int:
        return len(self.data)

    def array(self) -> np.ndarray:
        raw = _codec("decompressor", zstandard.ZstdDecompressor).decompress(self.data)
        return np.frombuffer(raw, self.dtype).reshape(self.shape)


def _codec(name: str, make: Callable[[], Any]) -> Any:
    codec = getattr(_CODECS, name, None)
    if codec is None:
        codec = make()
        setattr(_CODECS, name, codec)
    return codec


def _squeeze(codes: np.ndarray) -> np.ndarray | Squeezed:
    """``codes`` compressed when that saves enough (quantized disparity and confidence are mostly
    smooth or blocky), else ``codes`` themselves (noisy codes that zstd cannot shrink)."""
    compressor = _codec("compressor", lambda: zstandard.ZstdCompressor(level=ZSTD_LEVEL))
    data = compressor.compress(np.ascontiguousarray(codes).data)
    if len(data) > KEEP_IF_AT_MOST * codes.nbytes:
        return codes
    own = mmap.mmap(-1, len(data))
    own.write(data)
    return Squeezed(own, codes.dtype, codes.shape)


def _codes(held: np.ndarray | Squeezed) -> np.ndarray:
    return held.array() if isinstance(held, Squeezed) else held


def _pack_disparity(d: np.ndarray) -> tuple[np.ndarray, np.float32] | None:
    """Codes of ``d`` (H x W float32 px) and their steps per pixel, or None when they would not give
    ``d`` back exactly: uint8 (``NAN_CODE_U8`` = NaN) when the codes in ``d``'s own step fit in a
    byte (the simulator's 1/4 px below 64 px), else int16 in 1/64 px steps.

    Exactness is read off ``d * 64`` itself: multiplying and dividing a float32 by a power of two is
    exact, so codes ``c`` give ``d`` back bit for bit when every ``d * 64`` is a whole number in the
    int16 range and no value is -0.0 (its code 0 comes back as +0.0). That is a few passes over the
    frame where unpacking and comparing took three times as many (the capture thread pays it per
    frame)."""
    if d.dtype != np.float32 or d.size == 0:
        return None
    with np.errstate(invalid="ignore"):
        scaled = d * DISPARITY_SCALE
        nan = np.isnan(scaled)
        if np.any(nan & (d.view(np.uint32) != _NAN_BITS)):  # a NaN of other bits than the one unpacking writes
            return None
        lo, hi = np.fmin.reduce(scaled, axis=None), np.fmax.reduce(scaled, axis=None)
        if np.isnan(lo):  # nothing matched
            return np.full(d.shape, NAN_CODE, np.int16), DISPARITY_SCALE
        if not (lo > -32768 and hi <= 32767):
            return None
        whole = np.rint(scaled)
        if np.count_nonzero(whole != scaled) != np.count_nonzero(nan):  # NaN != NaN: only a fraction adds to the left
            return None
        if lo <= 0 <= hi and np.any(np.signbit(d) & (d == 0)):
            return None
        codes = whole.astype(np.int16)
    codes[nan] = NAN_CODE
    if lo >= 0:
        bits = int(np.bitwise_or.reduce(codes, axis=None)) & 0x7FFF  # NAN_CODE is bit 15 alone: no valid code has it
        shift = min(6, (bits & -bits).bit_length() - 1) if bits else 6  # the coarsest power of two dividing every code
        if int(hi) >> shift < NAN_CODE_U8:
            small = (codes >> shift).astype(np.uint8)
            small[nan] = NAN_CODE_U8
            return small, np.float32(DISPARITY_SCALE / (1 << shift))
    return codes, DISPARITY_SCALE


def _unpack_disparity(codes: np.ndarray, scale: np.float32) -> np.ndarray:
    d = codes.astype(np.float32)
    d /= scale
    d[codes == (NAN_CODE_U8 if codes.dtype == np.uint8 else NAN_CODE)] = np.nan
    return d


def _pack_confidence(c: np.ndarray) -> np.ndarray | None:
    """uint8 codes of ``c`` (H x W float32 in [0, 1]), or None when they would not give ``c`` back exactly."""
    if c.dtype != np.float32 or c.size == 0 or not (c.min() >= 0 and c.max() <= 1):
        return None
    codes = np.rint(c * CONFIDENCE_SCALE).astype(np.uint8)
    return codes if np.array_equal(_unpack_confidence(codes), c) else None


def _unpack_confidence(codes: np.ndarray) -> np.ndarray:
    c = codes.astype(np.float32)
    c /= CONFIDENCE_SCALE
    return c


@dataclass(eq=False)
class PackedFrame:
    """A :class:`measure.Frame` with its disparity and confidence as codes where that is exact, and
    without its image where the frame's source can make it again.

    ``camera``, ``baseline_m``, ``doffs``, ``meta`` and ``shape`` answer without unpacking;
    :meth:`unpack` gives the frame back (the same object while anyone still holds it); ``image``
    is the image, made again when it is not held."""

    held_image: np.ndarray | None  # None: made by meta[REBUILD_IMAGE] when asked for
    disparity: np.ndarray | Squeezed  # uint8 or int16 codes (compressed or not), or the float32 disparity itself
    disparity_scale: np.float32  # codes per pixel (1 for the float32 disparity)
    confidence: np.ndarray | Squeezed | None  # uint8 codes (compressed or not), float32 values or None
    camera: PinholeCamera
    baseline_m: float
    doffs: float
    timestamp: float
    meta: Mapping[str, Any]
    _last: Any = None  # weak reference to the last unpacked Frame

    @classmethod
    def pack(cls, frame: Frame) -> PackedFrame:
        codes = _pack_disparity(frame.disparity)
        disparity, scale = (frame.disparity, np.float32(1.0)) if codes is None else (_squeeze(codes[0]), codes[1])
        confidence = None if frame.confidence is None else _pack_confidence(frame.confidence)
        image = None if callable(frame.meta.get(REBUILD_IMAGE)) else frame.image
        packed = cls(image, disparity, scale,
                     frame.confidence if confidence is None else _squeeze(confidence), frame.camera, frame.baseline_m,
                     frame.doffs, frame.timestamp, frame.meta)  # fmt: skip
        packed._last = weakref.ref(frame)
        return packed

    @property
    def shape(self) -> tuple[int, int]:
        return self.disparity.shape  # type: ignore[return-value]

    @property
    def image(self) -> np.ndarray:
        """The colour image: held, the unpacked frame's while it lives, else made again."""
        if self.held_image is not None:
            return self.held_image
        frame = self._last() if self._last is not None else None
        if frame is not None:
            return frame.image
        rebuild: Callable[[], np.ndarray] = self.meta[REBUILD_IMAGE]
        return rebuild()

    def keep_image(self) -> None:
        """Hold the image from now on (a frozen frame: measured, saved and drawn, each asking for it)."""
        if self.held_image is None:
            self.held_image = self.image

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held (image, disparity, confidence)."""
        image = 0 if self.held_image is None else self.held_image.nbytes
        return image + self.disparity.nbytes + (0 if self.confidence is None else self.confidence.nbytes)

    def unpack(self) -> Frame:
        """The frame, arrays as they were pushed (bit for bit)."""
        frame = self._last() if self._last is not None else None
        if frame is None:
            d = self.disparity if self.disparity.dtype == np.float32 else _unpack_disparity(_codes(self.disparity), self.disparity_scale)
            c = self.confidence
            if c is not None and c.dtype == np.uint8:
                c = _unpack_confidence(_codes(c))
            frame = Frame(self.image, d, self.camera, self.baseline_m, self.doffs, c, self.timestamp, self.meta)
            self._last = weakref.ref(frame)
        return frame
