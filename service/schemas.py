"""Request and response bodies of the HTTP API (pydantic models; every request field bounded and typed)."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, RootModel, Strict, create_model, field_validator, model_validator

from measure import MAX_FRAMES, METHODS, MeasureOptions, OptionField, describe_options, options_of

FiniteNumber = Annotated[float, Strict(), Field(allow_inf_nan=False)]
MAX_ID = 2**53 - 1  # the largest integer a JavaScript number holds exactly; far below SQLite's 2^63
Id = Annotated[int, Strict(), Field(ge=0, le=MAX_ID)]
PLAIN_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


def is_plain_name(text: str) -> bool:
    """Whether ``text`` is a plain folder name: letters, digits, '.', '_', '-', at most 64, not all
    dots; the whole text (a trailing newline is not part of a name)."""
    return PLAIN_NAME.fullmatch(text) is not None and text.strip(".") != ""


def _option_type(field: OptionField) -> Any:
    """The pydantic type of one MeasureOptions field, from its metadata (measure.Opt)."""
    opt, allowed = field.opt, field.choices()
    if allowed is not None:
        return Literal[tuple(allowed)]  # type: ignore[valid-type]
    bounds = {("gt" if opt.min_open else "ge"): opt.min} if opt.min is not None else {}
    if opt.max is not None:
        bounds["lt" if opt.max_open else "le"] = opt.max
    name = field.kind
    if name == "bool":
        return Annotated[bool, Strict()]
    if name == "int":
        odd = [AfterValidator(_odd)] if opt.odd else []
        return Annotated[int, Strict(), Field(**bounds), *odd]
    return Annotated[float, Field(allow_inf_nan=False, **bounds)]


def _odd(value: int) -> int:
    if value % 2 == 0:
        raise ValueError("must be odd")
    return value


class _Options(BaseModel):
    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="after")
    def _core_accepts(self) -> _Options:
        self.to_options()  # MeasureError is a ValueError: a 422 naming the option
        return self

    def to_options(self) -> MeasureOptions:
        """These options as the core's :class:`measure.MeasureOptions`."""
        return MeasureOptions(**self.model_dump())


# Built from MeasureOptions' field metadata: the bounds, defaults and method names are the core's.
OptionsIn = create_model(
    "OptionsIn",
    __base__=_Options,
    __doc__="Measurement options (measure.MeasureOptions); every field optional, bounds as the core's.",
    **{f.name: (_option_type(f), f.default) for f in options_of(MeasureOptions)},  # type: ignore[call-overload]
)


class MeasureIn(BaseModel):
    """``POST /api/measure`` body: the frame id and two points in pixels of its colour image."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Id
    p1: tuple[FiniteNumber, FiniteNumber]
    p2: tuple[FiniteNumber, FiniteNumber]
    options: OptionsIn = OptionsIn()
    # Measure over this many frames of a still scene: the frame and the ones received just before it
    # (measure.sequence; robust method only).
    frames: Annotated[int, Strict(), Field(ge=1, le=MAX_FRAMES)] = 1


Point = tuple[FiniteNumber, FiniteNumber]
MAX_SHAPE_POINTS = 256  # clicks of a path or an area; each leg of a path is a segment's measurement
ONE_CLICK = {"box": "a click on its top face", "height": "a click on the object"}
LEAST_CLICKS = {"path": (2, "in order along it"), "area": (3, "in order around it")}


class ShapeIn(BaseModel):
    """``POST /api/shapes`` body: a box, a height, a path or an area on frame ``frame_id``; ``points``
    in pixels of its colour image (box, height: exactly 1; path: >= 2; area: >= 3, in order);
    ``on`` a height's base plane (1 click on it, or >= 3 around a region of it; null: the plane the
    object stands on); ``options`` as ``POST /api/measure``'s."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Id
    kind: Literal["box", "height", "path", "area"]
    points: Annotated[list[Point], Field(min_length=1, max_length=MAX_SHAPE_POINTS)]
    on: Annotated[list[Point], Field(min_length=1, max_length=MAX_SHAPE_POINTS)] | None = None
    options: OptionsIn = OptionsIn()

    @model_validator(mode="after")
    def _clicks_fit_the_kind(self) -> ShapeIn:
        n, kind = len(self.points), self.kind
        if kind in ONE_CLICK and n != 1:
            raise ValueError(f"a {kind} takes exactly 1 point ({ONE_CLICK[kind]}), got {n}; send one point")
        if kind in LEAST_CLICKS and n < LEAST_CLICKS[kind][0]:
            least, order = LEAST_CLICKS[kind]
            raise ValueError(f"{'an' if kind == 'area' else 'a'} {kind} needs at least {least} points {order}, got {n}; add points")
        if self.on is not None and kind != "height":
            raise ValueError(f"'on' names the base plane of a height only; leave it out (or null) for a {kind}")
        if self.on is not None and len(self.on) == 2:
            raise ValueError("'on' is 1 click on the base plane or at least 3 around a region of it, got 2; add a click")
        return self


class BoardIn(BaseModel):
    """A printed ChArUco board: squares across and down, square and marker side in mm, ArUco dictionary."""

    model_config = ConfigDict(extra="forbid")
    squares_x: Annotated[int, Strict(), Field(ge=3, le=100)] = 11
    squares_y: Annotated[int, Strict(), Field(ge=3, le=100)] = 8
    square_mm: Annotated[float, Field(gt=0, le=3000, allow_inf_nan=False)] = 30.0
    marker_mm: Annotated[float, Field(gt=0, le=3000, allow_inf_nan=False)] = 22.0
    dictionary: Annotated[str, Strict(), Field(pattern=r"^DICT_[A-Z0-9_]{1,40}$")] = "DICT_5X5_100"


class CheckIn(BaseModel):
    """``POST /api/checks`` body: check the board on frame ``frame_id`` (and the ``frames - 1`` received
    before it); ``board`` as printed, or none for the source's own board (the simulator's) or the default."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Id
    frames: Annotated[int, Strict(), Field(ge=1, le=MAX_FRAMES)] = 1
    board: BoardIn | None = None


class RecordingIn(BaseModel):
    """``POST /api/recordings``: start or stop; ``out`` names a folder inside the server's recordings root."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "stop"]
    out: Annotated[str, Strict()] | None = None

    @field_validator("out")
    @classmethod
    def _plain_name(cls, v: str | None) -> str | None:
        if v is not None and not is_plain_name(v):
            raise ValueError(
                "out must be a plain folder name (letters, digits, '.', '_', '-'; at most 64; no '/' or '..'): "
                "recordings go inside the server's --recordings folder"
            )
        return v


class ReplayIn(BaseModel):
    """``POST /api/source/replay``: pause, play, step one frame, or seek to frame ``index`` (0-based)."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["pause", "play", "step", "seek"]
    index: Annotated[int, Strict(), Field(ge=0, le=10_000_000)] | None = None


class SourceOpenIn(BaseModel):
    """``POST /api/source``: play ``recording`` (a folder of the server's recordings root) in place of
    the server's source; ``null`` goes back to that source."""

    model_config = ConfigDict(extra="forbid")
    recording: Annotated[str, Field(min_length=1, max_length=200)] | None


class AnnotationIn(BaseModel):
    """``PATCH /api/measurements/{id}``: a name and a note for a measurement (omitted = unchanged)."""

    model_config = ConfigDict(extra="forbid")
    name: Annotated[str, Field(max_length=200)] | None = None
    note: Annotated[str, Field(max_length=4000)] | None = None


# ---------------------------------------------------------------------------------------------
# Response bodies. The routes build plain dicts (encoded off the event loop where it matters) and
# declare these for /docs; tests/service/test_api_schemas.py checks that real answers validate against them.


class _Out(BaseModel):
    model_config = ConfigDict(extra="forbid")


class OptionFieldOut(_Out):
    """One option as measure.fields.describe gives it: spelling, type, default, bounds, unit, help."""

    name: str
    key: str
    aliases: list[str]
    type: str
    default: Any
    required: bool
    default_text: str
    min: float | None
    max: float | None
    min_open: bool
    max_open: bool
    odd: bool
    multiple_of: int | None
    choices: list[str] | None
    unit: str
    help: str
    target: bool
    joined: list[Any] | None
    example: Any


class OptionsOut(_Out):
    """``GET /api/options``: the method names, every measure option (default, bounds, unit, help) and
    the most frames one measurement pools, from the core's one description."""

    methods: list[str]
    fields: list[OptionFieldOut]
    frames: dict[str, int]


def options_description() -> dict[str, Any]:
    """The body of ``GET /api/options``."""
    return {"methods": list(METHODS), "fields": describe_options(MeasureOptions), "frames": {"min": 1, "max": MAX_FRAMES}}


class TruthOut(_Out):
    """The simulator's ground truth of a frame (None for real sources): pixels, metres, what it is."""

    p1_px: list[float] | None
    p2_px: list[float] | None
    p1_m: list[float] | None
    p2_m: list[float] | None
    length_m: float | None
    target: str | None
    is_gap: bool | None


class FrameOut(_Out):
    """A frame of the ring: ``id`` for this service run, ``uid`` for the history; size in pixels,
    times in seconds since the epoch; ``replay_index`` the frame's 0-based index in the recording it is
    played from (a replay, a bag, a video file) and ``recording`` that recording's name; None and ""
    for a live source. ``has_confidence``: the frame carries the matcher's confidence map
    (``GET /api/frames/{id}/confidence.png``); False where its source gives none."""

    id: int
    uid: str
    width: int
    height: int
    timestamp: float
    received: float
    frozen: bool
    source: str
    meta: dict[str, str | int | float | bool | None]
    truth: TruthOut | None
    has_confidence: bool
    replay_index: int | None
    recording: str


class DepthOut(_Out):
    """Depth (m) and disparity (px) at pixel (``x``, ``y``); None where the disparity has no data."""

    frame_id: int
    x: int
    y: int
    disparity_px: float | None
    depth_m: float | None


class DepthScaleOut(_Out):
    """The disparity range (px) at the ends of ``disparity.png``'s colour map, the same as depth (m,
    near first), ``fx_baseline`` (px·m) and ``doffs`` (px) to place any depth, and the map's colours."""

    frame_id: int
    disparity_px: list[float] | None
    depth_m: list[float | None] | None
    fx_baseline: float
    doffs: float
    colors: list[str]


class HealthOut(_Out):
    """``status`` "degraded" with ``reasons`` (joined in ``reason``) when the next frame would not fit
    on the history's disk (``free_bytes`` < ``next_frame_bytes`` and the commit's headroom) or the
    source is down; ``recording_error`` says why the last recording stopped by itself."""

    status: Literal["ok", "degraded"]
    reason: str
    reasons: list[str]
    source_state: str
    source_message: str
    recording_error: str
    free_bytes: int | None
    next_frame_bytes: int | None
    frames: int
    ring_bytes: int  # the frames' arrays and cached encodings the ring holds (bytes)
    kernels: Literal["built ahead of time", "numba, just in time", ""]  # the measuring kernels ("" before the warm-up)
    uptime_s: float


class ReplayStatusOut(_Out):
    """A recorded source's position: ``kind`` "replay", "bag" or "video"; ``index`` (0-based) of the
    last frame delivered; ``frames`` in the recording (0: unknown, e.g. a video whose container does not
    list them); ``recording`` its name; ``recorded_source`` the source a native recording was made from."""

    kind: str
    paused: bool
    index: int | None
    frames: int
    recording: str
    recorded_source: str


class RecordingStatusOut(_Out):
    active: bool
    path: str | None
    frames: int
    error: str


class SourceStatusOut(_Out):
    """What the capture is doing: ``state`` (starting, streaming, reconnecting, ended, ...), the source's
    description, measured rate, reconnect counters, the replay's and the recording's status."""

    state: str
    message: str
    spec: str
    kind: str
    name: str
    serial: str
    width: int
    height: int
    fps: float
    depth: dict[str, Any] | None = Field(None, description="the depth post-processing the device applies "
                                         "(an OAK's stereo filters, confidence threshold, baseline); None where the source does not say")
    measured_fps: float
    frames: int
    retries: int
    retry_in_s: float | None
    replay: ReplayStatusOut | None
    home: str  # the server's own source while one of its recordings plays in its place; "" otherwise
    timeouts: int
    warnings: list[str]
    recording: RecordingStatusOut


class MeasurementOut(BaseModel):
    """A stored measurement: where it was clicked (``p1``, ``p2``, px), with which options, and the
    result (metres; None where not finite). ``samples_px`` and ``support`` (the per-sample arrays)
    are left out of history lists. ``weak_stretches``: where along the segment the matcher's support is
    weak (``measure.weak_stretches``), ``[t0, t1]`` fractions of the segment (0 = ``p1``, 1 = ``p2``);
    empty where none is, or the frame has no confidence; absent on measurements stored before it was
    kept. Fields the measuring core adds later are kept as they come."""

    model_config = ConfigDict(extra="allow")
    id: int
    created: float
    name: str
    note: str
    frame_id: int
    frame_uid: str
    source: str
    p1: list[float]
    p2: list[float]
    options: OptionsIn
    distance_m: float | None
    method: str
    fit: str
    p1_m: list[float | None]
    p2_m: list[float | None]
    basic_distance_m: float | None
    uncertainty_m: float | None
    n_samples: int
    n_valid: int
    n_support: int
    samples_px: list[list[float]] | None = None
    support: list[bool] | None = None
    gap_detected: bool
    warnings: list[str]
    elapsed_ms: float
    pinned: bool
    interval_m: list[float | None] | None = None
    quality: str | None = None
    reasons: list[str] | None = None
    frame_index: int | None = None
    weak_stretches: list[list[float]] | None = None
    kind: Literal["segment"] = "segment"


class ShapeOut(BaseModel):
    """A stored shape measurement (``POST /api/shapes``): the clicks (``points``, ``on``, px), the
    answer (``value`` in ``unit`` "m" or "m2", 1σ ``uncertainty``, 95 % ``interval``; None for a box,
    whose ``dimensions_m`` are length >= width and height with their 1σ and 95 % intervals), the
    verdict, ``draw_px`` (what to draw, px: a path's vertices, an area's corners, a height's top point
    and its foot, a box's 4 top then 4 base corners) and ``result``, the core's answer unabridged."""

    model_config = ConfigDict(extra="allow")
    id: int
    kind: Literal["box", "height", "path", "area"]
    created: float
    created_at: float
    name: str
    note: str
    frame_id: int
    frame_uid: str
    source: str
    options: OptionsIn
    points: list[list[float]]
    on: list[list[float]] | None
    quality: str
    reasons: list[str]
    value: float | None
    unit: Literal["m", "m2"]
    uncertainty: float | None
    interval: list[float | None] | None
    dimensions_m: list[float | None] | None
    dimension_sigmas_m: list[float | None] | None
    dimension_intervals_m: list[list[float | None]] | None
    draw_px: list[list[float | None]]
    result: dict[str, Any]
    elapsed_ms: float
    pinned: bool


class AnyMeasurementOut(RootModel[MeasurementOut | ShapeOut]):
    """A stored measurement of any kind: a segment (``kind`` "segment") or a shape."""


class MeasurementsOut(_Out):
    measurements: list[AnyMeasurementOut]


class ReopenOut(_Out):
    frame: FrameOut
    measurement: AnyMeasurementOut


class DeletedOut(_Out):
    deleted: int


class ChecksOut(_Out):
    """``GET /api/checks``: accuracy checks of `depthruler check`, newest first (each the JSON record
    the check wrote: source, serial, calibration hash, time, figures, findings)."""

    checks: list[dict[str, Any]]
    count: int
    file: str


class CheckOut(_Out):
    """``POST /api/checks``: the check's record as the checks log keeps it (status, figures, findings,
    source, serial, calibration hashes) with ``id``, the frames used and asked for (``frames_note`` says
    "used 2 of 3 frames ..." when the ring held fewer), the board and ``png_url``."""

    model_config = ConfigDict(extra="allow")
    id: str
    status: str
    figures: dict[str, Any]
    findings: list[dict[str, Any]]
    frame_id: int
    frame_ids: list[int]
    frames_requested: int
    frames_note: str | None = None
    board: dict[str, Any]
    png_url: str | None = None


def json_doc(model: type[BaseModel] | object, csv: bool = False) -> dict[str, object]:
    """Route arguments that document ``model`` as the 200 answer (and a CSV alternative with ``csv``)
    while the route returns its dict or a pre-encoded Response as it is (no validation pass on the
    hot paths)."""
    answer: dict[str, object] = {"model": model}
    if csv:
        answer["content"] = {"text/csv": {"schema": {"type": "string"}}}
    return {"response_model": None, "responses": {200: answer}}


def media_doc(*media_types: str, text: bool = False) -> dict[str, object]:
    """Route arguments that document a binary (image) or text (CSV) 200 answer of ``media_types``
    (the plain Response class, so no JSON body is listed beside them)."""
    from fastapi.responses import Response

    schema = {"type": "string"} if text else {"type": "string", "format": "binary"}
    return {
        "response_model": None,
        "response_class": Response,
        "responses": {200: {"content": {m: {"schema": schema} for m in media_types}}},
    }
