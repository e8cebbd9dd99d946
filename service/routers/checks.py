"""``/api/checks``: run the board check on frames of the ring, its picture, and the history of checks (newest first)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path, Query
from fastapi.responses import FileResponse

from history.checks import checks_path, picture_path, read_checks

from service.board_check import run_board_check
from service.deps import State
from service.schemas import CheckIn, CheckOut, ChecksOut, json_doc, media_doc

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


@router.post("/checks", **json_doc(CheckOut))
async def run_check(state: State, body: CheckIn) -> dict[str, Any]:
    """Check the accuracy of lengths on frame ``frame_id`` (frozen, so the ring keeps it) against a printed
    ChArUco board in view, keep it in the history with its picture, and answer its record. Runs on the
    measurement workers (429 when busy); 422 when no frame shows the board."""
    board = body.board.model_dump() if body.board is not None else None
    return await state.measures.run(run_board_check, state, body.frame_id, body.frames, board)


@router.get("/checks/{check_id}/check.png", **media_doc("image/png"))
def check_png(state: State, check_id: Annotated[str, Path(max_length=64)]) -> FileResponse:
    """The picture of a check run from the page: the board, its pairs coloured by error, the numbers."""
    try:
        path = picture_path(checks_path(state.store.path), check_id)
    except ValueError as exc:
        raise HTTPException(404, str(exc)) from None
    if not path.is_file():
        raise HTTPException(404, f"check {check_id} has no picture; checks from `depthruler check` keep theirs in --out")
    return FileResponse(path, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})
