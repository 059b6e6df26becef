"""Tags of job lines: kept by token until written, by number until acknowledged; the channel."""

from __future__ import annotations

import asyncio

from drivers.link.acks import Ack, AckChannel, Tags


def test_a_tag_follows_its_line_from_queue_to_acknowledgement() -> None:
    tags = Tags()
    tags.queued(1, ("layer", 0))
    tags.queued(2, ("layer", 1))
    tags.queued(3, None)  # untagged
    tags.written(1, 7)
    tags.written(2, 8)
    tags.written(3, 9)
    assert tags.acked(7) == ("layer", 0)
    assert tags.acked(9) is None
    assert tags.acked(8) == ("layer", 1)
    assert tags.acked(8) is None  # delivered once


def test_a_number_written_again_after_renumbering_takes_the_new_tag_and_cancel_drops() -> None:
    tags = Tags()
    tags.queued(1, "old")
    tags.written(1, 5)  # never acknowledged (the link failed over it, say)
    tags.queued(2, "new")
    tags.written(2, 5)  # line 5 of a new numbering
    assert tags.acked(5) == "new"
    tags.queued(3, "cancelled")
    tags.dropped(3)
    tags.written(3, 6)  # (a token is never written after a drop; nothing is left of it)
    assert tags.acked(6) is None
    tags.queued(4, "x")
    tags.written(4, 7)
    tags.clear()
    assert tags.acked(7) is None


def test_the_channel_delivers_in_order_and_ends_when_closed() -> None:
    async def main() -> tuple[list[Ack], list[Ack]]:
        channel = AckChannel()
        channel.put(Ack(1, "G1 X1", 0))
        early = channel.take()
        got: list[Ack] = []

        async def follow() -> None:
            async for ack in channel:
                got.append(ack)

        task = asyncio.create_task(follow())
        for n in range(2, 5):
            channel.put(Ack(n, f"G1 X{n}", n - 1))
            await asyncio.sleep(0)
        channel.close()
        channel.put(Ack(9, "G1 X9", 8))  # after close: dropped
        await asyncio.wait_for(task, 5)
        return early, got

    early, got = asyncio.run(main())
    assert [a.tag for a in early] == [0]
    assert [a.tag for a in got] == [1, 2, 3]
