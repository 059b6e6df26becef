"""What the MQTT tests share: an observer client that records what the bridge publishes,
the bridge's settings for a test broker, its topics, and a bridge run around a test body."""

from __future__ import annotations

import asyncio
import json
import ssl
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import aiomqtt
import pytest

from hostd.config import MqttConfig
from hostd.publishing.mqtt import MqttBridge
from support.brokers import HOST, Broker

PRINTER = "p1"
USER, SECRET = "farm", "s3cret"


@dataclass
class Received:
    topic: str
    payload: str
    retain: bool
    at: float


@dataclass
class Observer:
    """A second client on the broker that records what the bridge publishes."""

    client: aiomqtt.Client
    messages: list[Received] = field(default_factory=list)
    arrived: asyncio.Condition = field(default_factory=asyncio.Condition)

    async def collect(self) -> None:
        loop = asyncio.get_running_loop()
        async for message in self.client.messages:
            payload = message.payload
            text = payload.decode() if isinstance(payload, bytes) else str(payload)
            async with self.arrived:
                self.messages.append(
                    Received(str(message.topic), text, message.retain, loop.time())
                )
                self.arrived.notify_all()

    def on(self, topic: str) -> list[Received]:
        return [item for item in self.messages if item.topic == topic]

    async def wait_for(self, test: Callable[[], Any], timeout: float = 10.0) -> Any:
        """Wait until ``test()`` is truthy (re-checked on every message) and return it."""
        async with asyncio.timeout(timeout), self.arrived:
            await self.arrived.wait_for(test)
            return test()

    def last_json(self, topic: str) -> dict[str, Any] | None:
        items = self.on(topic)
        return json.loads(items[-1].payload) if items else None


def observer_client(broker: Broker, tls: ssl.SSLContext | None = None) -> aiomqtt.Client:
    creds = {"username": USER, "password": SECRET} if broker.users else {}
    return aiomqtt.Client(HOST, broker.port, tls_context=tls, identifier=None, **creds)


async def observe(
    broker: Broker, body: Callable[[Observer], Awaitable[None]], tls: ssl.SSLContext | None = None
) -> None:
    """Run ``body`` with an observer subscribed to the printer's topics and discovery."""
    async with observer_client(broker, tls) as client:
        observer = Observer(client)
        await client.subscribe(f"hostd/{PRINTER}/#", qos=1)
        await client.subscribe("homeassistant/#", qos=1)
        collector = asyncio.create_task(observer.collect(), name="observer")
        try:
            await body(observer)
        finally:
            collector.cancel()


def settings(broker: Broker, **changes: Any) -> MqttConfig:
    values: dict[str, Any] = {"enabled": True, "host": HOST, "port": broker.port}
    if broker.users:
        values.update(username=USER, password=SECRET)
    values.update(changes)
    return MqttConfig(**values)


def topic(name: str) -> str:
    return f"hostd/{PRINTER}/{name}"


async def with_bridge(bridge: MqttBridge, body: Callable[[], Awaitable[None]]) -> None:
    """Run ``body`` while ``bridge.run()`` runs; then stop the bridge as the daemon would."""
    task = asyncio.create_task(bridge.run(), name="bridge")
    try:
        async with asyncio.timeout(10):
            await bridge.connected.wait()
        await body()
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
