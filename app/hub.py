"""Fan-out of the live stream to every connected page.

The loop thread serialises each message once and calls :meth:`Hub.publish`; the asyncio loop puts the
text on each client's bounded queue and a per-client task sends it. A slow page loses its oldest
messages instead of slowing the loop or the other pages.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools

CLIENT_QUEUE = 512


class Client:
    """One websocket: an outgoing queue (asyncio side only) and counters."""

    def __init__(self, client_id: int) -> None:
        self.id = client_id
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=CLIENT_QUEUE)
        self.sent = 0
        self.dropped = 0

    def offer(self, text: str) -> None:
        """Enqueue without waiting; drop the oldest message when the page falls behind."""
        if self.queue.full():
            try:
                self.queue.get_nowait()
                self.dropped += 1
            except asyncio.QueueEmpty:
                pass
        self.queue.put_nowait(text)


class Hub:
    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.clients: dict[int, Client] = {}
        self._ids = itertools.count(1)
        self.published = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    def add(self, first: str | None = None) -> Client:
        """Register a client (call on the asyncio loop). ``first`` is queued before any stream message."""
        client = Client(next(self._ids))
        if first is not None:
            client.offer(first)
        self.clients[client.id] = client
        return client

    def remove(self, client: Client) -> None:
        self.clients.pop(client.id, None)

    def publish(self, text: str) -> None:
        """Thread-safe: send ``text`` to every page."""
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        self.published += 1
        with contextlib.suppress(RuntimeError):  # the event loop is shutting down
            loop.call_soon_threadsafe(self._fanout, text)

    def _fanout(self, text: str) -> None:
        for client in list(self.clients.values()):
            client.offer(text)

    @staticmethod
    async def pump(client: Client, send: object) -> None:
        """Send the client's queue until cancelled; ``send`` is ``websocket.send_text``."""
        while True:
            text = await client.queue.get()
            await send(text)  # type: ignore[operator]
            client.sent += 1
