"""The request guard: one ASGI middleware in front of every route, before any body is parsed.

It refuses, in this order:
- a request with more than one ``Host`` header, or more than one ``Origin`` (400): which one a
  later reader takes is not defined;
- a ``Host`` that is not one of the names the server is bound to (400): a DNS-rebinding page
  reaches 127.0.0.1 under its own name and would otherwise read the API as same-origin; a ``Host``
  whose port is not a number (``127.0.0.1:evil.com``) is no such name;
- with a token set, an ``/api`` request (but ``/api/health``) without it (401), before its body is
  read, so that an unauthenticated client holds no connection while it sends one;
- a state-changing request (POST, PUT, PATCH, DELETE) from another site (403): its ``Origin``
  is not this server's, or the browser says ``Sec-Fetch-Site: cross-site`` / ``same-site``;
- a POST or PUT or PATCH whose ``Content-Type`` is not JSON (415): an HTML form on a foreign page
  can send a body-less or form POST without a CORS preflight, never an ``application/json`` one;
- a body longer than ``max_body_bytes`` (413): at once when ``Content-Length`` says so, and by
  counting the streamed bytes otherwise, so nothing large is ever buffered or parsed.
Requests without ``Origin`` / ``Sec-Fetch-Site`` (curl, scripts) pass the site check: they are not
a browser carrying someone's ambient access.
"""

from __future__ import annotations

import hmac
import json
from collections.abc import Awaitable, Callable, Iterable
from typing import Any
from urllib.parse import parse_qs, urlsplit

Scope = dict[str, Any]
Message = dict[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
UNSAFE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
BODY_METHODS = frozenset({"POST", "PUT", "PATCH"})
MAX_BODY_BYTES = 16 * 1024  # far above the largest body of this API, a measurement request


def host_name(host: str) -> str:
    """The name part of a ``Host`` header value (no port; IPv6 without brackets), lower case; the whole
    value when its port is not a number (``127.0.0.1:evil.com`` names no host of ours)."""
    host = host.strip().lower()
    if host.startswith("["):
        end = host.find("]")
        port = host[end + 1 :] if end >= 0 else ""
        return host[1:end] if end >= 0 and (port == "" or (port[:1] == ":" and port[1:].isdigit())) else host
    if host.count(":") == 1:
        name, port = host.split(":")
        return name if port.isdigit() else host
    return host


def allowed_hosts_for(bind: str, extra: Iterable[str] = ()) -> tuple[str, ...]:
    """Host names to accept when bound to ``bind``: loopback names, the bound name, and ``extra``;
    ``("*",)`` (any) when bound to every interface, where the token is the protection."""
    if bind in ("0.0.0.0", "::", ""):
        return ("*",)
    return tuple(dict.fromkeys([*LOOPBACK_HOSTS, host_name(bind), *(host_name(h) for h in extra)]))


class RequestGuard:
    """ASGI middleware; see the module docstring. ``allowed_hosts`` holds names (``"*"`` = any)."""

    def __init__(
        self, app: ASGIApp, *, allowed_hosts: Iterable[str] = LOOPBACK_HOSTS, max_body_bytes: int = MAX_BODY_BYTES, token: str = ""
    ) -> None:
        self.app = app
        self.token = token.encode()
        hosts = [h if h == "*" else host_name(h) for h in allowed_hosts]
        self.any_host = "*" in hosts
        self.allowed_hosts = frozenset(hosts)
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        raw = [(k.decode("latin-1").lower(), v.decode("latin-1")) for k, v in scope.get("headers", [])]
        headers = dict(raw)
        refusal = self._refusal(scope, [k for k, _ in raw], headers)
        if refusal is not None:
            await _send_json(send, *refusal)
            return
        if scope["method"] not in BODY_METHODS and "content-length" not in headers and "transfer-encoding" not in headers:
            await self.app(scope, receive, send)
            return
        await self._limited(scope, receive, send)

    def _authorised(self, scope: Scope, headers: dict[str, str]) -> bool:
        path = scope.get("path", "")
        if not path.startswith("/api/") or path == "/api/health":
            return True
        header = headers.get("authorization", "")
        if header.lower().startswith("bearer "):
            given = header[7:].strip()
        else:
            query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
            given = (query.get("token") or [""])[0]
        return hmac.compare_digest(given.encode(), self.token)

    def _refusal(self, scope: Scope, names: list[str], headers: dict[str, str]) -> tuple[Any, ...] | None:
        """(status, detail[, extra headers]) of the first rule of the module docstring the request breaks."""
        method = scope["method"]
        for name in ("host", "origin"):
            if names.count(name) > 1:
                return 400, f"the request has {names.count(name)} {name.title()} headers; send one"
        host = headers.get("host", "")
        if not self.any_host and host_name(host) not in self.allowed_hosts:
            return 400, (
                f"Host {host!r} is not a name this server answers to ({', '.join(sorted(self.allowed_hosts))}); "
                "open it by one of those names, or start it with --allowed-host NAME"
            )
        if self.token and not self._authorised(scope, headers):
            return 401, "missing or wrong token: send 'Authorization: Bearer <token>' or add ?token=<token>", [(b"www-authenticate", b"Bearer")]
        if method in UNSAFE_METHODS:
            origin = headers.get("origin")
            site = headers.get("sec-fetch-site", "").lower()
            if origin is not None and _origin_netloc(origin) != host.strip().lower():
                return 403, f"cross-site request refused: Origin {origin!r} is not this server ({host}); use the page this server serves"
            if site in ("cross-site", "same-site"):
                return 403, f"cross-site request refused (Sec-Fetch-Site: {site}); use the page this server serves"
        if method in BODY_METHODS:
            ctype = headers.get("content-type", "").split(";", 1)[0].strip().lower()
            if ctype != "application/json":
                return 415, f"{method} needs 'Content-Type: application/json' (got {ctype or 'none'}), even without a body"
        length = headers.get("content-length")
        if length is not None:
            if not length.strip().isdigit():
                return 400, f"Content-Length {length!r} is not a number"
            if int(length) > self.max_body_bytes:
                return 413, f"request body of {int(length)} bytes is over the limit of {self.max_body_bytes} bytes"
        return None

    async def _limited(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Read the body (at most ``max_body_bytes``: this API's bodies are tiny) before the app
        sees it, and hand it over in one message; over the limit the app is never called."""
        chunks: list[bytes] = []
        seen = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client went away
            chunk = message.get("body", b"")
            seen += len(chunk)
            if seen > self.max_body_bytes:
                await _send_json(send, 413, f"request body is over the limit of {self.max_body_bytes} bytes")
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        delivered = False

        async def replay() -> Message:
            nonlocal delivered
            if not delivered:
                delivered = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def _origin_netloc(origin: str) -> str:
    if origin.strip().lower() == "null":
        return "\0null"  # opaque origins (sandboxed frames, file://) never match a host
    return urlsplit(origin.strip()).netloc.lower()


async def _send_json(send: Send, status: int, detail: str, extra: list[tuple[bytes, bytes]] = ()) -> None:  # type: ignore[assignment]
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), (b"connection", b"close")]
    await send({"type": "http.response.start", "status": status, "headers": headers + list(extra)})
    await send({"type": "http.response.body", "body": body})
