"""``/api/checks``: the history of accuracy checks (`depthruler check`), newest first."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query

from history.checks import checks_path, read_checks

from service.deps import State
from service.schemas import ChecksOut, json_doc

router = APIRouter(prefix="/api", tags=["checks"])


@router.get("/checks", **json_doc(ChecksOut))
def checks(
    state: State,
    serial: Annotated[str | None, Query(max_length=200, description="Only this device serial.")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> dict[str, Any]:
    path = checks_path(state.store.path)
    items = read_checks(path, serial=serial, limit=limit)
    return {"checks": items, "count": len(items), "file": str(path)}
