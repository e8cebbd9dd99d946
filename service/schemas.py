"""Request bodies of the HTTP API (pydantic models; every field bounded and typed)."""

from __future__ import annotations

from typing import Annotated, Literal

import re

from pydantic import BaseModel, ConfigDict, Field, Strict, field_validator

FiniteNumber = Annotated[float, Strict(), Field(allow_inf_nan=False)]
MAX_ID = 2**53 - 1  # the largest integer a JavaScript number holds exactly; far below SQLite's 2^63
Id = Annotated[int, Strict(), Field(ge=0, le=MAX_ID)]
PLAIN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


class OptionsIn(BaseModel):
    """Measurement options (MeasureOptions); every field optional."""

    model_config = ConfigDict(extra="forbid")
    method: Literal["robust", "paper", "basic"] = "robust"
    support_fraction: Annotated[float, Field(ge=0.5, le=1.0, allow_inf_nan=False)] = 0.5
    window: Annotated[int, Strict(), Field(ge=1, le=51)] = 5
    extension_px: Annotated[int, Strict(), Field(ge=3, le=500)] = 25
    gap_detection: Annotated[bool, Strict()] = True
    seed: Annotated[int, Strict(), Field(ge=0, le=2**32 - 1)] = 0


class MeasureIn(BaseModel):
    """``POST /api/measure`` body: the frame id and two points in pixels of its colour image."""

    model_config = ConfigDict(extra="forbid")
    frame_id: Id
    p1: tuple[FiniteNumber, FiniteNumber]
    p2: tuple[FiniteNumber, FiniteNumber]
    options: OptionsIn = OptionsIn()


class RecordingIn(BaseModel):
    """``POST /api/recordings``: start or stop; ``out`` names a folder inside the server's recordings root."""

    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "stop"]
    out: Annotated[str, Strict()] | None = None

    @field_validator("out")
    @classmethod
    def _plain_name(cls, v: str | None) -> str | None:
        if v is not None and (not PLAIN_NAME.match(v) or v.strip(".") == ""):
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


class AnnotationIn(BaseModel):
    """``PATCH /api/measurements/{id}``: a name and a note for a measurement (omitted = unchanged)."""

    model_config = ConfigDict(extra="forbid")
    name: Annotated[str, Field(max_length=200)] | None = None
    note: Annotated[str, Field(max_length=4000)] | None = None
