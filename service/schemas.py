"""Request bodies of the HTTP API (pydantic models; every field bounded and typed)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, Strict

FiniteNumber = Annotated[float, Strict(), Field(allow_inf_nan=False)]


class OptionsIn(BaseModel):
    """Measurement options (MeasureOptions); every field optional."""

    model_config = ConfigDict(extra="forbid")
    method: Literal["robust", "paper", "basic"] = "robust"
    support_fraction: Annotated[float, Field(ge=0.5, le=1.0, allow_inf_nan=False)] = 0.5
    window: Annotated[int, Strict(), Field(ge=1, le=51)] = 5
    extension_px: Annotated[int, Strict(), Field(ge=3, le=500)] = 25
    gap_detection: Annotated[bool, Strict()] = True
    seed: Annotated[int, Strict(), Field(ge=0)] = 0


class MeasureIn(BaseModel):
    """``POST /api/measure`` body: the frame id and two points in pixels of its colour image."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Annotated[int, Strict()]
    p1: tuple[FiniteNumber, FiniteNumber]
    p2: tuple[FiniteNumber, FiniteNumber]
    options: OptionsIn = OptionsIn()
    # Measure over this many frames of a still scene: the frame and the ones received just before it
    # (measure.sequence; robust method only).
    frames: Annotated[int, Strict(), Field(ge=1, le=30)] = 1


class RecordingIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "stop"]
    out: str | None = None


class ReplayIn(BaseModel):
    """``POST /api/source/replay``: pause, play, step one frame, or seek to frame ``index`` (0-based)."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["pause", "play", "step", "seek"]
    index: Annotated[int, Strict(), Field(ge=0, le=10_000_000)] | None = None


class AnnotationIn(BaseModel):
    """``PATCH /api/measurements/{id}``: a name and a note for a measurement (omitted = unchanged)."""

    model_config = ConfigDict(extra="forbid")
    name: Annotated[str, Field(max_length=200)] | None = None
    note: Annotated[str, Field(max_length=4000)] | None = None
