"""Same origin only: a page on another site must not reach the dashboard, let alone drive the robot.

Two checks, both on every request:

- **Host.** HTTP requests and websockets whose ``Host`` header names a host not in the allowed set are refused
  (400 / close 1008). A DNS-rebinding page reaches 127.0.0.1 under its own name, so its requests carry that
  name: refusing unknown names shuts it out. The allowed set is the loopback names by default, plus the names
  given with ``sage serve --allow-host`` when serving on a LAN.
- **Origin.** A websocket (``/ws``, the viser relay) whose ``Origin`` is not the dashboard's own origin is
  refused before it is accepted, so a page on another site never gets a control token. A websocket without an
  ``Origin`` header does not come from a browser page (browsers always send one) and is let through.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable, MutableMapping
from typing import Any
from urllib.parse import urlsplit

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")


def allowed_hosts(bind_host: str, extra: Iterable[str] = ()) -> frozenset[str]:
    """Loopback names, the address the server is bound to (unless it is a wildcard) and ``extra``."""
    names = {*LOOPBACK_NAMES, *(h.strip().lower().strip("[]") for h in extra if h.strip())}
    if bind_host and bind_host not in ("0.0.0.0", "::"):
        names.add(bind_host.lower().strip("[]"))
    return frozenset(names)


def host_name(value: str) -> str:
    """``"example.com:8000"`` -> ``"example.com"``; ``"[::1]:8000"`` -> ``"::1"``."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key.lower() == name:
            return value.decode("latin-1")
    return None


def same_origin(scope: Scope) -> bool:
    """True when the websocket's ``Origin`` (if any) is ``http(s)://<the Host header>``."""
    origin = _header(scope, b"origin")
    if origin is None:
        return True
    host = (_header(scope, b"host") or "").strip().lower()
    parts = urlsplit(origin.strip().lower())
    return parts.scheme in ("http", "https") and bool(host) and parts.netloc == host


class OriginGuard:
    """ASGI middleware: refuse unknown ``Host`` names (HTTP and websockets) and cross-origin websockets."""

    def __init__(self, app: ASGIApp, hosts: frozenset[str]) -> None:
        self.app, self.hosts = app, hosts
        self.refused = 0
        """Requests refused so far (for tests and the bench)."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope.get("type")
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        host = host_name(_header(scope, b"host") or "")
        if host not in self.hosts:
            self.refused += 1
            await self._refuse(kind, send, receive, f"host {host!r} is not allowed")
            return
        if kind == "websocket" and not same_origin(scope):
            self.refused += 1
            await self._refuse(kind, send, receive, "cross-origin websocket refused")
            return
        await self.app(scope, receive, send)

    @staticmethod
    async def _refuse(kind: str, send: Send, receive: Receive, reason: str) -> None:
        if kind == "websocket":
            await receive()  # the websocket.connect event
            await send({"type": "websocket.close", "code": 1008, "reason": reason})
            return
        body = f"refused: {reason}\n".encode()
        await send(
            {
                "type": "http.response.start",
                "status": 400,
                "headers": [
                    (b"content-type", b"text/plain; charset=utf-8"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
