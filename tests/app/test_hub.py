"""The per-page outgoing queue: stream messages give way when a page falls behind, replies never do."""

from __future__ import annotations

import asyncio

import pytest

from app.hub import CLIENT_QUEUE, Client, Hub


def test_a_full_queue_drops_the_oldest_stream_message_and_keeps_every_reply_in_order() -> None:
    async def run() -> tuple[list[str], int]:
        client = Client(1)
        await client.reply("reply 0")
        for i in range(CLIENT_QUEUE + 10):
            client.offer(f"step {i}")
        sent = [await client.next()]  # room for one reply
        await client.reply("reply 1")
        sent += [await client.next() for _ in range(len(client))]
        return sent, client.dropped

    sent, dropped = asyncio.run(run())
    assert sent[0] == "reply 0" and sent[-1] == "reply 1"
    steps = [text for text in sent if text.startswith("step")]
    assert dropped == 11 and steps == [f"step {i}" for i in range(11, CLIENT_QUEUE + 10)]


def test_a_page_flooding_the_server_waits_for_room_and_loses_no_reply() -> None:
    """Replies outnumber the queue; stream messages keep arriving: every reply is sent, in order."""

    async def run() -> list[str]:
        client = Client(1)
        sent: list[str] = []

        async def send(text: str) -> None:
            sent.append(text)
            await asyncio.sleep(0)

        pump = asyncio.create_task(Hub.pump(client, send))
        for i in range(3 * CLIENT_QUEUE):
            await client.reply(f"reply {i}")
            client.offer(f"step {i}")
        while len(client):
            await asyncio.sleep(0)
        pump.cancel()
        with pytest.raises(asyncio.CancelledError):
            await pump
        return sent

    sent = asyncio.run(run())
    assert [text for text in sent if text.startswith("reply")] == [f"reply {i}" for i in range(3 * CLIENT_QUEUE)]


def test_when_every_queued_message_is_a_reply_a_stream_message_is_the_one_dropped() -> None:
    async def run() -> tuple[list[str], int]:
        client = Client(1)
        for i in range(CLIENT_QUEUE):
            await client.reply(f"reply {i}")
        client.offer("step")
        return [await client.next() for _ in range(len(client))], client.dropped

    sent, dropped = asyncio.run(run())
    assert sent == [f"reply {i}" for i in range(CLIENT_QUEUE)] and dropped == 1
