"""Fan-out of the live stream to every connected page.

The loop thread serialises each message once and calls :meth:`Hub.publish`; the asyncio loop puts the
text on each client's bounded queue and a per-client task sends it. A slow page loses its oldest stream
messages instead of slowing the loop or the other pages; the replies to its own messages are never lost.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
from collections import deque

CLIENT_QUEUE = 512


class Client:
    """One websocket: an outgoing queue of at most ``CLIENT_QUEUE`` messages, in order (asyncio side only), and
    counters. Stream messages (:meth:`offer`) never wait: when the page falls behind, the oldest stream message
    gives way. Replies to the page's own messages (:meth:`reply`) are never dropped: they wait for room, so a page
    that floods the server slows only itself."""

    def __init__(self, client_id: int) -> None:
        self.id = client_id
        self._items: deque[tuple[bool, str]] = deque()  # (a reply?, text), in the order they are sent
        self._changed = asyncio.Event()  # an item came (for the sender) or left (for a reply waiting for room)
        self.sent = 0
        self.dropped = 0

    def __len__(self) -> int:
        return len(self._items)

    def offer(self, text: str) -> None:
        """Enqueue a stream message without waiting; when full, the oldest stream message is dropped (or this one,
        if every queued message is a reply)."""
        if len(self._items) >= CLIENT_QUEUE:
            self.dropped += 1
            oldest = next((i for i, (is_reply, _) in enumerate(self._items) if not is_reply), None)
            if oldest is None:
                return
            del self._items[oldest]
        self._items.append((False, text))
        self._changed.set()

    async def reply(self, text: str) -> None:
        """Enqueue a reply, waiting while the queue is full."""
        while len(self._items) >= CLIENT_QUEUE:
            self._changed.clear()
            await self._changed.wait()
        self._items.append((True, text))
        self._changed.set()

    async def next(self) -> str:
        """The next message to send, waiting for one."""
        while not self._items:
            self._changed.clear()
            await self._changed.wait()
        _, text = self._items.popleft()
        self._changed.set()  # room for a reply waiting for it
        return text


class Hub:
    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self.clients: dict[int, Client] = {}
        self._ids = itertools.count(1)
        self.published = 0

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    def add(self) -> Client:
        """Register a client (call on the asyncio loop); a welcome queued with :meth:`Client.reply` before the next
        await comes before any stream message."""
        client = Client(next(self._ids))
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
            text = await client.next()
            await send(text)  # type: ignore[operator]
            client.sent += 1
