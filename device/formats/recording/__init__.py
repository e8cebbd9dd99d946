"""Recording and replay of frames in depthruler's directory format (docs/design.md "Recording format").

Layout of one recording directory::

    manifest.json          format, format_version, source info, camera, baseline_m, doffs, created,
                           frame_count (a hint only: frames.jsonl is the truth), complete
    frames.jsonl           one JSON line per frame, append-only: index, timestamp, files, meta
    color/000000.png       BGR uint8, lossless
    disparity/000000.png   uint16 = round(d * 64), 0 = invalid (NaN); 1/64 px steps, d < 1024 px
    confidence/000000.png  optional, uint8 = round(c * 255)
    raw/left/000000.png    optional (keep_raw): the rectified stereo pair, so SGBM can be re-run
    raw/right/000000.png
    extra/KEY/000000.npy   optional: image-sized arrays found in frame.meta (e.g. Middlebury's
                           "gt_disparity"), stored losslessly with numpy

Durability: per frame, every image file is written and fsync'd (and its directory), then the
frames.jsonl line is appended and fsync'd. A frame exists only once its line is complete, so a
crash or a pulled cable loses at most the frame in flight; the reader skips a truncated last line
and reports it in ``Recording.problems``. The manifest is replaced atomically (temp file, fsync,
``os.replace``) after the first frame, then at most once a second and on close.

Disparity that cannot be stored: a disparity of 1024 px or more raises :class:`RecordingError`
(nothing of that frame is written); negative disparity and disparity below 1/128 px (it would
round to the invalid code 0) are stored as invalid and counted in the frame's line as
``disparity_dropped``. Meta values are kept when JSON can hold them; a dataclass (e.g. the
simulator's ``Truth``) is kept as a JSON summary of its small fields (its ``depth_m`` image is
dropped); other values are dropped and their keys listed in ``meta_dropped``.

Replay: ``replay:DIR?loop=1&realtime=1&speed=1`` yields the frames again (colour bit-identical,
disparity within 1/128 px). At the end of a recording without ``loop`` ``read`` raises
:class:`EndOfRecording`, a :class:`SourceEnded`: the stream has ended.

Modules: ``format`` (constants, codes, encoding, durable file operations), ``writer``
(:class:`RecordingWriter`), ``reader`` (:func:`open_recording`, :class:`Recording`) and ``replay``
(:class:`ReplaySource`, the ``replay:`` spec). This package re-exports what callers use.
"""

from device.formats.recording.format import (
    DISPARITY_SCALE,
    FORMAT,
    FORMAT_VERSION,
    FRAMES,
    MANIFEST,
    MAX_DISPARITY_CODE,
    RAW_KEYS,
    EndOfRecording,
    RecordingNotFound,
    decode_confidence,
    decode_disparity,
    encode_confidence,
    encode_disparity,
    jsonable,
)
from device.formats.recording.reader import FrameEntry, Recording, open_recording, summarize
from device.formats.recording.replay import ReplayConfig, ReplaySource, config_from_spec
from device.formats.recording.writer import RecordingWriter

__all__ = [
    "DISPARITY_SCALE", "FORMAT", "FORMAT_VERSION", "FRAMES", "MANIFEST", "MAX_DISPARITY_CODE", "RAW_KEYS",
    "EndOfRecording", "FrameEntry", "Recording", "RecordingNotFound", "RecordingWriter", "ReplayConfig", "ReplaySource",
    "decode_confidence", "decode_disparity", "encode_confidence", "encode_disparity", "config_from_spec", "jsonable",
    "open_recording", "summarize",
]  # fmt: skip
