"""Playing one of the server's recordings in place of its own source (the page's "Open as replay"
after a recording stops), and going back to that source.

Only a folder inside the recordings root can be played (the name is checked as a new recording's
is); an active recording is stopped first, since it would otherwise record its own replay. The
capture switches sources (:meth:`service.capture.Capture.switch`): frames already in the ring, frozen
ones included, stay measurable.
"""

from __future__ import annotations

from device import make_source

from service.recorder import BadRecordingName, RecorderError
from service.schemas import is_plain_name
from service.state import ServiceState


class NoSuchRecording(RecorderError):
    """The named folder of the recordings root is not a recording (HTTP 404)."""


def play_recording(state: ServiceState, name: str) -> None:
    """Replay ``name`` (a folder of the recordings root), looping at its recorded pace."""
    root = state.recorder.root
    path = root / name
    if not is_plain_name(name) or path.parent != root or path.is_symlink():
        raise BadRecordingName(f"recording must be a plain folder name inside {root} (got {name!r})")
    if not (path / "manifest.json").is_file():
        raise NoSuchRecording(f"{path} is not a recording (it has no manifest.json); record one with the Record button")
    if state.recorder.status()["active"]:
        state.recorder.stop()
    spec = f"replay:{path}?loop=1&realtime=1"
    state.capture.switch(lambda: make_source(spec), spec)


def play_home(state: ServiceState) -> None:
    """Back to the source the server was started with (nothing to do when it is playing it)."""
    if state.home is not None and state.capture.spec != state.home[1]:
        if state.recorder.status()["active"]:
            state.recorder.stop()
        state.capture.switch(*state.home)


def home_spec(state: ServiceState) -> str:
    """The server's own source while a recording plays in its place, else ""."""
    return state.home[1] if state.home is not None and state.capture.spec != state.home[1] else ""
