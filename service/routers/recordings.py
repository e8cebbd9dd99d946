"""``/api/recordings``: record the live stream, and its status."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..schemas import RecordingIn
from ..state import State

router = APIRouter(prefix="/api/recordings", tags=["recordings"])


@router.get("")
def recording_status(state: State) -> dict[str, Any]:
    return state.recorder.status()


@router.post("")
def recording(state: State, body: RecordingIn) -> dict[str, Any]:
    return state.recorder.start(body.out) if body.action == "start" else state.recorder.stop()
