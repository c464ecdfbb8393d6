"""viser on the dashboard's own origin: an HTTP proxy for its client files and a websocket relay.

viser runs its own websocket server in its own thread on a loopback port; it is not an ASGI app. The
dashboard serves it at ``/viser/`` so the page and the 3D view share one origin: the page can then
catch key presses inside the embedded view (before viser's camera keys see them). The viewer derives
its websocket address from its page address, ``/viser/`` -> ``ws://<host>/viser``, and speaks a
``viser-v<version>`` subprotocol that the relay passes through.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import urllib.error
import urllib.request

import websockets
from fastapi import WebSocket, WebSocketDisconnect
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

log = logging.getLogger(__name__)


class ViserProxy:
    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self.port = port
        self.host = host
        self._cache: dict[str, tuple[int, bytes, str]] = {}
        self.relays = 0

    def _fetch(self, path: str) -> tuple[int, bytes, str]:
        url = f"http://{self.host}:{self.port}/{path}"
        try:
            with urllib.request.urlopen(url, timeout=10) as response:
                return (
                    response.status,
                    response.read(),
                    response.headers.get("Content-Type", "application/octet-stream"),
                )
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read(), exc.headers.get("Content-Type", "text/plain")

    async def http(self, path: str) -> Response:
        """The viewer's files, fetched once from viser and kept (they never change while it runs)."""
        if ".." in path.split("/"):
            return Response("not found", status_code=404)
        key = path or "index.html"
        cached = self._cache.get(key)
        if cached is None:
            try:
                cached = await run_in_threadpool(self._fetch, path)
            except OSError as exc:
                return Response(f"viser is not reachable: {exc}", status_code=502)
            if cached[0] == 200:
                self._cache[key] = cached
        status, body, content_type = cached
        return Response(body, status_code=status, media_type=content_type, headers={"Cache-Control": "no-cache"})

    async def relay(self, websocket: WebSocket) -> None:
        """Pass a viewer's websocket through to viser, both directions, binary and text alike."""
        offered = [p.strip() for p in websocket.headers.get("sec-websocket-protocol", "").split(",") if p.strip()]
        subprotocol = next((p for p in offered if p.startswith("viser-v")), None)
        try:
            upstream = await websockets.connect(
                f"ws://{self.host}:{self.port}",
                subprotocols=[subprotocol] if subprotocol else None,  # type: ignore[list-item]
                max_size=None,
                compression=None,
                open_timeout=10,
                ping_interval=None,
            )
        except (TimeoutError, OSError, websockets.exceptions.WebSocketException) as exc:
            log.warning("viser relay could not reach viser: %s", exc)
            await websocket.close(code=1011)
            return
        await websocket.accept(subprotocol=upstream.subprotocol or subprotocol)
        self.relays += 1

        async def downstream() -> None:
            async for message in upstream:
                if isinstance(message, bytes):
                    await websocket.send_bytes(message)
                else:
                    await websocket.send_text(message)

        async def upstream_pump() -> None:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                if message.get("bytes") is not None:
                    await upstream.send(message["bytes"])
                elif message.get("text") is not None:
                    await upstream.send(message["text"])

        tasks = [asyncio.create_task(downstream()), asyncio.create_task(upstream_pump())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, Exception):
                    await task
            await upstream.close()
            with contextlib.suppress(Exception):
                await websocket.close()
