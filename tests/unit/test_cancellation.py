"""A task told to stop stops: no cancellation is lost on Python 3.11.

The daemon hung on SIGTERM about once in five runs: aiomqtt waits for a
publication's acknowledgement with ``asyncio.wait_for``, which on 3.11 returns the
result when the acknowledgement and the cancellation come in the same loop
iteration, so the MQTT task published on and then waited for ever.
"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from support.waiting import until

from drivers.link.tasks import cancel_and_wait
from hostd.publishing.mqtt_calls import publish


class AckedLikeAiomqtt:
    """A client whose publication waits for its acknowledgement as aiomqtt 2 does."""

    def __init__(self) -> None:
        self.acknowledged: asyncio.Future[None] | None = None
        self.published: list[str] = []

    async def publish(self, topic: str, payload: Any, *, qos: int, retain: bool) -> None:
        self.published.append(topic)
        self.acknowledged = asyncio.get_running_loop().create_future()
        await asyncio.wait_for(self.acknowledged, 10)


async def _ack_and_cancel_together(client: AckedLikeAiomqtt, task: asyncio.Task[Any]) -> None:
    acknowledged = await until(lambda: client.acknowledged, 10, "the publication", interval=0)
    acknowledged.set_result(None)  # the broker's PUBACK ...
    task.cancel()  # ... and the task group's cancellation in the same iteration


def test_a_cancellation_that_meets_the_acknowledgement_still_stops_the_publisher() -> None:
    async def scenario() -> tuple[bool, list[str]]:
        client = AckedLikeAiomqtt()

        async def publisher() -> None:
            while True:  # like the bridge's event loop: publish, then wait for more
                await publish(client, "hostd/p/event", b"{}", qos=1)  # type: ignore[arg-type]
                await asyncio.Event().wait()

        task = asyncio.create_task(publisher())
        await _ack_and_cancel_together(client, task)
        done, _ = await asyncio.wait({task}, timeout=2)
        return task in done and task.cancelled(), client.published

    stopped, published = asyncio.run(scenario())
    assert published == ["hostd/p/event"]
    assert stopped, "the publisher lost its cancellation and waits for ever"


def test_cancel_and_wait_takes_the_child_s_cancellation_but_not_the_caller_s() -> None:
    async def scenario() -> bool:
        second_cleaning = asyncio.Event()

        async def slow_to_stop(cleaning: asyncio.Event | None = None) -> None:
            try:
                await asyncio.Event().wait()
            finally:
                if cleaning is not None:
                    cleaning.set()
                await asyncio.sleep(0.05)  # cleans up before it ends

        async def caller() -> str:
            child = asyncio.create_task(slow_to_stop())
            await asyncio.sleep(0)
            await cancel_and_wait(child)  # the child's cancellation is not an error
            second = asyncio.create_task(slow_to_stop(second_cleaning))
            await asyncio.sleep(0)
            await cancel_and_wait(second)  # the caller is cancelled while it waits here
            return "ran on"

        task = asyncio.create_task(caller())
        await second_cleaning.wait()  # the caller waits for the second child to end
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return task.cancelled()

    assert asyncio.run(scenario()), "the caller ran on after it was told to stop"
