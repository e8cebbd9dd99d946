"""Connection-level limits for uvicorn: header and body deadlines, a connection cap with a clean 503,
and file descriptors kept for the history.

uvicorn closes idle keep-alive connections, but a connection that sends its request headers or its
body a little at a time is never timed out (docs/decisions/connection-limits.md). :func:`guarded`
wraps uvicorn's HTTP protocol class (h11 or httptools) so that each connection has one deadline
at a time:

1. from its opening, or from the end of the previous response: the request's headers complete
   within ``header_timeout_s`` (else 408 and close; a connection that sent nothing is just closed);
2. from the end of the headers: the body complete within ``body_timeout_s`` (else 408 and close);
3. while the app answers: none (the routes bound their own waits).

A connection beyond :func:`connection_cap` is answered 503 at once and closed, before it is read.
:func:`serve` raises the process's soft limit on open files to its hard limit, keeps
``reserved_fds`` of them for the database, its readers, frame files and recordings, shortens the
interpreter's switch interval (``SWITCH_INTERVAL_S``) and runs uvicorn.
"""

from __future__ import annotations

import asyncio
import ctypes
import json
import resource
import sys
from dataclasses import dataclass
from typing import Any

# The event loop gives up the interpreter lock at every socket write and waits for it again behind the
# measurement, presave and capture threads; at the default 5 ms each wait, and each response costs
# several (docs/decisions/measure-pool.md).
SWITCH_INTERVAL_S = 0.0005
LINGER_S = 0.5  # a refused connection is read and dropped this long, so the 503 is not lost to a reset


@dataclass(frozen=True)
class ConnectionLimits:
    """Seconds: ``header_timeout_s`` (opening or previous answer to the end of the headers),
    ``body_timeout_s`` (end of the headers to the end of the body), ``keep_alive_s`` (idle between
    requests); ``max_connections`` open at once; ``reserved_fds`` file descriptors never used for
    connections."""

    header_timeout_s: float = 10.0
    body_timeout_s: float = 10.0
    keep_alive_s: float = 5.0
    max_connections: int = 4096
    reserved_fds: int = 256


def raise_fd_limit() -> int:
    """Raise the soft limit on open files to the hard limit (as Go's runtime does); the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY or soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    return soft


def connection_cap(limits: ConnectionLimits, fd_limit: int) -> int:
    """Connections allowed at once: ``max_connections``, less where the open-files limit minus the
    reserve is smaller (at least 1)."""
    return max(1, min(limits.max_connections, fd_limit - limits.reserved_fds))


def _answer(status: int, reason: str, detail: str) -> bytes:
    body = json.dumps({"detail": detail}).encode()
    head = (
        f"HTTP/1.1 {status} {reason}\r\ncontent-type: application/json\r\ncontent-length: {len(body)}\r\n"
        "connection: close\r\n" + ("retry-after: 1\r\n" if status == 503 else "") + "\r\n"
    )
    return head.encode("latin-1") + body


class CoalescingTransport:
    """A transport whose writes in one turn of the event loop go to the socket as one write: uvicorn
    writes a response's head and its body apart, and every socket write gives up the interpreter lock
    and waits for it again behind the worker threads (docs/decisions/measure-pool.md). Closing or
    ending the stream writes what is held first; everything else is the wrapped transport's."""

    def __init__(self, transport: asyncio.Transport) -> None:
        self._transport = transport
        self._held: list[bytes] = []

    def write(self, data: bytes) -> None:
        if not self._held:
            asyncio.get_running_loop().call_soon(self.flush)
        self._held.append(bytes(data))

    def writelines(self, chunks: Any) -> None:
        for chunk in chunks:
            self.write(chunk)

    def flush(self) -> None:
        if self._held:
            data = b"".join(self._held)
            self._held.clear()
            if not self._transport.is_closing():
                self._transport.write(data)

    def write_eof(self) -> None:
        self.flush()
        self._transport.write_eof()

    def close(self) -> None:
        self.flush()
        self._transport.close()

    def abort(self) -> None:
        self._held.clear()
        self._transport.abort()

    def get_write_buffer_size(self) -> int:
        return self._transport.get_write_buffer_size() + sum(map(len, self._held))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)


def guarded(base: type[asyncio.Protocol], limits: ConnectionLimits, cap: int) -> type[asyncio.Protocol]:
    """uvicorn's protocol class ``base`` with the deadlines and the cap of the module docstring."""

    class Guarded(base):  # type: ignore[misc, valid-type]
        _phase = ""  # "header", "body" or "app"
        _timer: asyncio.TimerHandle | None = None
        _timed: Any = None  # the request cycle the body deadline is for
        _heard = False  # bytes arrived in this header phase
        _refused = False

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(CoalescingTransport(transport))  # type: ignore[arg-type]
            if len(self.connections) > cap:
                self._refuse()
                return
            self._track()

        def data_received(self, data: bytes) -> None:
            if self._refused:
                return  # read and dropped until the linger ends
            self._heard = True
            super().data_received(data)
            if not self.transport.is_closing():
                self._track()

        def eof_received(self) -> bool | None:
            if self._refused:
                self.transport.close()
                return None
            return super().eof_received()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._track()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel()
            super().connection_lost(exc)

        def _track(self) -> None:
            cycle = self.cycle
            if cycle is None or cycle.response_complete:
                if self._phase != "header":
                    self._phase, self._heard = "header", False
                    self._arm(limits.header_timeout_s)
            elif cycle.more_body:
                if self._phase != "body" or self._timed is not cycle:
                    self._phase, self._timed = "body", cycle
                    self._arm(limits.body_timeout_s)
            elif self._phase != "app":
                self._phase = "app"
                self._cancel()

        def _arm(self, seconds: float) -> None:
            self._cancel()
            self._timer = asyncio.get_running_loop().call_later(seconds, self._expire)

        def _cancel(self) -> None:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

        def _expire(self) -> None:
            self._timer = None
            if self.transport.is_closing():
                return
            if self._phase == "body" and not self.cycle.response_started:
                self.transport.write(_answer(408, "Request Timeout", f"the request body did not arrive within {limits.body_timeout_s:g} s"))
            elif self._phase == "header" and self._heard:
                self.transport.write(_answer(408, "Request Timeout", f"the request headers did not arrive within {limits.header_timeout_s:g} s"))
            self.transport.close()

        def _refuse(self) -> None:
            self._refused = True
            detail = f"the server holds {cap} connections, its limit; retry in a second"
            self.transport.write(_answer(503, "Service Unavailable", detail))
            if self.transport.can_write_eof():
                self.transport.write_eof()
            asyncio.get_running_loop().call_later(LINGER_S, self.transport.close)

    Guarded.__name__ = Guarded.__qualname__ = f"Guarded{base.__name__}"
    return Guarded


def protocol_class(http: str = "auto") -> type[asyncio.Protocol]:
    """uvicorn's HTTP protocol class: httptools where installed (uvicorn's "auto"), else h11."""
    if http in ("auto", "httptools"):
        try:
            from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

            return HttpToolsProtocol
        except ImportError:
            if http == "httptools":
                raise
    from uvicorn.protocols.http.h11_impl import H11Protocol

    return H11Protocol


M_MMAP_THRESHOLD, M_ARENA_MAX = -3, -8  # glibc's mallopt parameters
MMAP_THRESHOLD_BYTES = 1 << 20
MALLOC_ARENAS = 2  # one per core: each arena of the ~16 threads otherwise keeps what its thread freed


def return_large_blocks() -> None:
    """Have glibc map every block of ``MMAP_THRESHOLD_BYTES`` or more on its own, so a freed frame
    array goes back to the system: its threshold otherwise grows to the largest freed block (32 MB at
    most) and frame-sized arrays, made and dropped by many threads, stay in its arenas. No-op off glibc."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
        libc.mallopt(M_ARENA_MAX, MALLOC_ARENAS)
    except (OSError, AttributeError):
        pass


def serve(app: Any, host: str, port: int, limits: ConnectionLimits, *, log_level: str = "warning", http: str = "auto") -> None:
    """Run ``app`` with uvicorn on ``host:port`` under ``limits`` until it is stopped."""
    import uvicorn

    cap = connection_cap(limits, raise_fd_limit())
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    return_large_blocks()
    uvicorn.run(
        app, host=host, port=port, log_level=log_level, access_log=False,
        http=guarded(protocol_class(http), limits, cap), timeout_keep_alive=limits.keep_alive_s,  # type: ignore[arg-type]
    )  # fmt: skip
