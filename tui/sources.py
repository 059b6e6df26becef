"""Where the dashboard gets status from and sends commands to: the control socket or MQTT."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any, Protocol

from hostd.api import ControlClient, ControlError, Snapshot


@dataclass(frozen=True)
class StatusItem:
    """A snapshot of one printer."""

    printer: str
    snapshot: Snapshot


@dataclass(frozen=True)
class EventItem:
    """A job event of one printer."""

    printer: str
    event: dict[str, Any]


class Source(Protocol):
    """A stream of status and events, and a way to send commands back.

    ``query`` sends a request whose reply the dashboard reads (``layer``,
    ``estimate``: see :mod:`hostd.api`) and returns the reply; a source that
    cannot answer such requests (MQTT carries status and commands only) raises
    :class:`Unanswered`, and the dashboard says that view needs the control socket.
    A source without ``query`` is treated the same way.
    """

    label: str

    def stream(self) -> AsyncIterator[StatusItem | EventItem]: ...

    async def command(self, printer: str, cmd: str, **args: Any) -> None: ...

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]: ...


class Unanswered(ControlError):
    """This source cannot answer that request (it needs the daemon's control socket)."""


class SocketSource:
    """One printer over its daemon's control socket."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.label = f"socket {path}"

    async def stream(self) -> AsyncIterator[StatusItem | EventItem]:
        """Status and events; reconnects every second while the daemon is away."""
        while True:
            try:
                async with ControlClient(self.path) as client:
                    first = await client.status()
                    yield StatusItem(first.printer.id, first)
                    async for item in client.subscribe():
                        if "status" in item:
                            snap: Snapshot = item["status"]
                            yield StatusItem(snap.printer.id, snap)
                        else:
                            yield EventItem("", item["event"])
            except (ControlError, OSError, json.JSONDecodeError):
                yield StatusItem("", Snapshot(state="offline", error="daemon not reachable"))
            await asyncio.sleep(1.0)

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        """Send one command; raises ControlError with the daemon's reason when refused."""
        async with ControlClient(self.path) as client:
            await client.request(cmd, **args)

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one request and return the daemon's reply; ControlError when refused."""
        async with ControlClient(self.path) as client:
            return await client.request(cmd, **args)


class MqttSource:
    """A fleet of printers over an MQTT broker (topics ``hostd/<printer>/...``)."""

    def __init__(self, host: str, port: int = 1883, username: str = "", password: str = "") -> None:
        self.host = host
        self.port = port
        self.username = username or None
        self.password = password or None
        self.label = f"mqtt {host}:{port}"
        self._client: Any = None

    async def stream(self) -> AsyncIterator[StatusItem | EventItem]:
        """Status and events of every printer on the broker; reconnects with a pause."""
        import aiomqtt

        while True:
            try:
                async with aiomqtt.Client(
                    self.host, self.port, username=self.username, password=self.password
                ) as client:
                    self._client = client
                    await client.subscribe("hostd/+/status")
                    await client.subscribe("hostd/+/event")
                    async for message in client.messages:
                        parts = str(message.topic).split("/")
                        payload = json.loads(bytes(message.payload or b"{}"))
                        if parts[-1] == "status":
                            yield StatusItem(parts[1], Snapshot.from_dict(payload))
                        else:
                            yield EventItem(parts[1], payload)
            except (aiomqtt.MqttError, json.JSONDecodeError, UnicodeDecodeError):
                self._client = None
                yield StatusItem("", Snapshot(state="offline", error="broker not reachable"))
            await asyncio.sleep(2.0)

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        """Publish a command to ``hostd/<printer>/cmd`` (the daemon answers on ``event``)."""
        if self._client is None:
            raise ControlError("not connected to the broker")
        await self._client.publish(f"hostd/{printer}/cmd", json.dumps({"cmd": cmd, **args}))

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]:
        """MQTT carries no replies to read: always :class:`Unanswered`."""
        raise Unanswered(f"{cmd}: needs the daemon's control socket (hostd tui --socket)")
