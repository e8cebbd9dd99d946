"""The HTTP answers of domain errors: each exception class raised below the routers is mapped once,
here, to a status; the answer is JSON ``{"detail": message}``, the message saying what to change.

:func:`install` registers one handler per class of :data:`STATUS` on an app (a subclass not listed
takes its nearest listed base's status), and the answer to a request body that fails validation.
"""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from check.errors import CheckError
from history.checks import CheckHistoryError
from history.errors import FrameDropped, FrameNotSaved, MeasurementUnknown, SavedFrameUnreadable, StoreError, StoreFull
from measure import MeasureError

from service import playback, recorder
from service.frame_errors import NoConfidence
from service.frames import FrameGone, FrameUnknown, NotAReplay, SeekOutOfRange, TooManyWaiters
from service.workers import Busy

STATUS: dict[type[Exception], int] = {
    FrameUnknown: 404,
    FrameGone: 410,
    NoConfidence: 404,  # the frame exists; its source gives no confidence map
    TooManyWaiters: 429,
    Busy: 429,
    NotAReplay: 409,
    SeekOutOfRange: 422,
    MeasureError: 422,
    MeasurementUnknown: 404,
    FrameNotSaved: 404,
    FrameDropped: 410,
    SavedFrameUnreadable: 500,
    StoreError: 500,  # nothing was stored
    StoreFull: 507,
    CheckError: 422,  # no board in the frames, or a board that cannot be
    CheckHistoryError: 500,  # the check ran but its record or picture could not be kept
    recorder.RecorderError: 409,
    recorder.RecordingUnavailable: 503,
    recorder.BadRecordingName: 422,
    recorder.CannotRecord: 400,
    playback.NoSuchRecording: 404,
}
HEADERS: dict[type[Exception], dict[str, str]] = {TooManyWaiters: {"Retry-After": "1"}, Busy: {"Retry-After": "1"}}


def _answer(exc: Exception) -> JSONResponse:
    cls = next(c for c in type(exc).__mro__ if c in STATUS)
    message = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)  # KeyError's str() quotes
    return JSONResponse({"detail": message}, status_code=STATUS[cls], headers=HEADERS.get(cls))


async def _domain(_: Request, exc: Exception) -> JSONResponse:
    return _answer(exc)


def validation_message(exc: RequestValidationError) -> tuple[str, list[dict[str, str]]]:
    """One line for a request that failed validation (``loc: msg (got input)``; for a body that is
    not JSON, where and why it does not parse), and the errors as a list."""
    errors = []
    for e in exc.errors():
        loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body") or "body"
        if e.get("type") == "json_invalid":
            where = f"at character {e['loc'][-1]}" if len(e.get("loc", ())) > 1 else "at its start"
            reason = (e.get("ctx") or {}).get("error", "invalid JSON")
            errors.append({"loc": "body", "msg": f"the body is not valid JSON {where} ({reason}); send a JSON object", "input": ""})
            continue
        errors.append({"loc": loc, "msg": str(e.get("msg", "invalid")), "input": repr(e.get("input"))[:80]})
    text = "; ".join(f"{e['loc']}: {e['msg']}" + (f" (got {e['input']})" if e["input"] else "") for e in errors)
    return text, errors


async def _invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
    text, errors = validation_message(exc)
    return JSONResponse({"detail": text, "errors": errors}, status_code=422)


def install(app: FastAPI) -> None:
    """Register the handlers of :data:`STATUS` and of validation errors on ``app``."""
    for cls in STATUS:
        app.add_exception_handler(cls, _domain)
    app.add_exception_handler(RequestValidationError, _invalid)  # type: ignore[arg-type]
