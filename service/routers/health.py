"""``/api/health`` and ``/api/source``: is the service up, and what is the source doing."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, HTTPException

from ..frames import ReplayControlError
from ..schemas import ReplayIn
from ..state import State

router = APIRouter(prefix="/api", tags=["health"])


@router.get("/health")
def health(state: State) -> dict[str, Any]:
    status = state.capture.status()
    return {
        "status": "ok",
        "source_state": status["state"],
        "frames": len(state.ring),
        "uptime_s": time.time() - state.started,
        "store_errors": state.store.write_errors[-5:],
    }


@router.get("/source")
def source_status(state: State) -> dict[str, Any]:
    return {**state.capture.status(), "recording": state.recorder.status()}


@router.post("/source/replay")
def replay_control(state: State, body: ReplayIn) -> dict[str, Any]:
    """Pause, play, step or seek a replay; answers the replay status (``paused``, ``index``, ``frames``)."""
    try:
        return state.capture.control(body.action, body.index)
    except ReplayControlError as exc:
        raise HTTPException(409 if "not a replay" in str(exc) else 422, str(exc)) from None
