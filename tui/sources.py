"""Where the dashboard gets status from and sends commands to: the control socket or MQTT."""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import json
import os
import random
import ssl
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any, Protocol

from hostd.api import ControlClient, ControlError, Snapshot

GONE = "offline: its connection to the broker was lost"  # a printer's last will, as shown


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


@dataclass(frozen=True)
class AvailabilityItem:
    """A printer's ``online`` topic: True on ``online``, False on its last will (``offline``)."""

    printer: str
    online: bool


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


def parse_brokers(text: str, default_port: int = 1883) -> list[tuple[str, int]]:
    """``HOST[:PORT][,HOST[:PORT]...]`` as (host, port) pairs; ValueError names a bad entry."""
    brokers: list[tuple[str, int]] = []
    for entry in (part.strip() for part in text.split(",")):
        host, colon, port = entry.rpartition(":") if entry.count(":") == 1 else ("", "", "")
        host = host if colon else entry
        if not host or any(ch.isspace() for ch in host):
            raise ValueError(f"broker {entry!r}: expected HOST or HOST:PORT")
        if colon and not (port.isdigit() and 1 <= int(port) <= 65535):
            raise ValueError(f"broker {entry!r}: the port must be a number in 1..65535")
        brokers.append((host, int(port) if colon else default_port))
    return brokers


def tls_context(cafile: str = "", certfile: str = "", keyfile: str = "") -> ssl.SSLContext:
    """A TLS client context checking the broker's certificate (and host name).

    ``cafile``: the CA (PEM) that signed the broker's certificate, instead of the
    system's CAs. ``certfile`` and ``keyfile`` (PEM, together): this client's own
    certificate, for a broker that requires one. ValueError names the file at fault.
    """
    if bool(certfile) != bool(keyfile):
        raise ValueError("a client certificate needs both --certfile and --keyfile")
    for what, path in (("CA file", cafile), ("certificate", certfile), ("key", keyfile)):
        if path and not os.path.isfile(path):
            raise ValueError(f"{what} {path}: no such file")
    try:
        context = ssl.create_default_context(cafile=cafile or None)
    except (ssl.SSLError, OSError) as exc:
        raise ValueError(f"CA file {cafile}: not a PEM certificate ({exc})") from exc
    if certfile:
        try:
            context.load_cert_chain(certfile, keyfile)
        except (ssl.SSLError, OSError) as exc:
            raise ValueError(
                f"certificate {certfile} with key {keyfile}: cannot be loaded ({exc})") from exc
    return context


class MqttSource:
    """Printers over an MQTT broker (topics ``hostd/<printer>/...``): a fleet or one printer.

    ``brokers`` are tried in turn (a cluster's nodes): when the connection drops
    or is refused, the next one is tried after a short jittered pause that grows
    while none answers. With ``printer`` set, only that printer is followed and its
    last will (``offline``) arrives as a status with state ``offline``.
    """

    def __init__(
        self,
        host: str | list[tuple[str, int]],
        port: int = 1883,
        username: str = "",
        password: str = "",
        *,
        tls: bool | ssl.SSLContext = False,
        printer: str | None = None,
    ) -> None:
        self.brokers = [(host, port)] if isinstance(host, str) else list(host)
        if not self.brokers:
            raise ValueError("no MQTT broker given")
        self.host, self.port = self.brokers[0]
        self.username = username or None
        self.password = password or None
        # True: the system's CAs; a context (``tls_context``): its CA and client certificate
        self.tls: ssl.SSLContext | None = (
            tls if isinstance(tls, ssl.SSLContext) else ssl.create_default_context() if tls
            else None)
        self.printer = printer
        names = ",".join(f"{h}:{p}" for h, p in self.brokers)
        self.label = f"mqtt {names}" + (f" · {printer}" if printer else "")
        self.connected_to = ""
        self._client: Any = None
        self._requests = itertools.count(1)

    async def stream(self) -> AsyncIterator[StatusItem | EventItem]:
        """Status and events; a printer's last will arrives as an ``offline`` status."""
        last: dict[str, Snapshot] = {}
        async for item in self.fleet_stream():
            if isinstance(item, AvailabilityItem):
                if item.online:
                    continue
                before = last.get(item.printer, Snapshot())
                yield StatusItem(item.printer, dataclasses.replace(
                    before, state="offline", error=GONE))
                continue
            if isinstance(item, StatusItem) and item.printer:
                last[item.printer] = item.snapshot
            yield item

    async def fleet_stream(self) -> AsyncIterator[StatusItem | EventItem | AvailabilityItem]:
        """Status, events and availability of every printer followed, across reconnects."""
        from tui.mqtt_wire import WireClient, WireError

        rng = random.Random()
        failures = 0
        who = self.printer or "+"
        for host, port in itertools.cycle(self.brokers):
            client = WireClient(
                host, port, client_id=f"hostd-tui-{rng.getrandbits(48):012x}",
                username=self.username, password=self.password,
                tls=self.tls,
            )
            try:
                async with client:
                    self._client = client
                    self.connected_to = f"{host}:{port}"
                    failures = 0
                    client.subscribe(f"hostd/{who}/status", qos=0)  # the newest wins anyway
                    client.subscribe(f"hostd/{who}/online", qos=1)
                    client.subscribe(f"hostd/{who}/event", qos=1)
                    async for message in client.messages():
                        item = _decode(message.topic, message.payload)
                        if item is not None:
                            yield item
            except WireError as exc:
                yield StatusItem("", Snapshot(state="offline", error=str(exc)))
            finally:
                self._client = None
                self.connected_to = ""
            failures += 1
            # the next node at once after a drop; a growing pause once every node refused
            ceiling = min(10.0, 0.5 * 2 ** max(0, failures // len(self.brokers)))
            await asyncio.sleep(rng.uniform(ceiling / 4, ceiling / 2))
        raise AssertionError("unreachable")  # pragma: no cover

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        """Publish a command to ``hostd/<printer>/cmd``; a refusal comes back as an event."""
        client = self._client
        if client is None:
            raise ControlError("not connected to the broker")
        request = {"cmd": cmd, **args, "id": f"tui-{next(self._requests)}"}
        try:
            await client.publish(f"hostd/{printer}/cmd", json.dumps(request).encode(), qos=1)
        except OSError as exc:
            raise ControlError(f"not sent: {exc}") from exc

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]:
        """MQTT carries no replies to read: always :class:`Unanswered`."""
        raise Unanswered(f"{cmd}: needs the daemon's control socket (hostd tui --socket)")


def _decode(topic: str, payload: Any) -> StatusItem | EventItem | AvailabilityItem | None:
    """One message of ``hostd/<printer>/<kind>`` as an item; a malformed status as an error."""
    parts = topic.split("/")
    if len(parts) != 3:
        return None
    printer, kind = parts[1], parts[2]
    raw = bytes(payload or b"")
    if kind == "online":
        return AvailabilityItem(printer, raw.strip() == b"online")
    try:
        data = json.loads(raw or b"{}")
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        if kind == "event":
            return EventItem(printer, data)
        return StatusItem(printer, Snapshot.from_dict(data))
    except (ValueError, TypeError, AttributeError, RecursionError) as exc:
        if kind != "status":
            return None
        return StatusItem(printer, Snapshot(state="error", error=f"unreadable status: {exc}"))
