"""``/api/options``: the measure options' one description, for the page and any other client."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service.schemas import OptionsOut, json_doc, options_description

router = APIRouter(prefix="/api", tags=["options"])


@router.get("/options", **json_doc(OptionsOut))
def options() -> dict[str, Any]:
    """The method names, every measure option with its default, bounds (``min``/``max``, ``odd``),
    unit and help, and the frames one measurement may pool (``frames.min``..``frames.max``)."""
    return options_description()
