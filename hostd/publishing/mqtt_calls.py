"""aiomqtt's publish and subscribe, made safe to cancel on Python 3.11.

aiomqtt waits for the broker's acknowledgement with :func:`asyncio.wait_for`. On
Python 3.11 that function returns the result when the acknowledgement and a
cancellation arrive in the same loop iteration, and the cancellation is lost: a
task stopped by its task group at that moment would publish on and then wait
for ever (the daemon hung on SIGTERM). These wrappers raise it again
(:func:`drivers.link.tasks.cancel_safe`).
"""

from __future__ import annotations

from typing import Any

import aiomqtt

from drivers.link.tasks import cancel_safe


async def publish(client: aiomqtt.Client, topic: str, payload: Any, *,
                  qos: int = 1, retain: bool = False) -> None:
    """:meth:`aiomqtt.Client.publish` that never swallows a cancellation."""
    await cancel_safe(client.publish(topic, payload, qos=qos, retain=retain))


async def subscribe(client: aiomqtt.Client, topic: str, *, qos: int = 1) -> None:
    """:meth:`aiomqtt.Client.subscribe` that never swallows a cancellation."""
    await cancel_safe(client.subscribe(topic, qos=qos))
