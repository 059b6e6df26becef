"""Where the dashboard gets status from and sends commands to: the control socket or MQTT."""

from __future__ import annotations

import asyncio
import contextlib
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
QUERY_TIMEOUT_S = 15.0  # a request over MQTT unanswered this long fails with a message


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
    ``estimate``: see :mod:`hostd.api`) and returns the reply, or raises
    :class:`ControlError` with the reason (refused, or no reply in time). A source
    that cannot answer such requests at all raises :class:`Unanswered` (or has no
    ``query``), and the dashboard says that view is not available.
    """

    label: str

    def stream(self) -> AsyncIterator[StatusItem | EventItem]: ...

    async def command(self, printer: str, cmd: str, **args: Any) -> None: ...

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]: ...


class Unanswered(ControlError):
    """This source cannot answer that request."""


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

    Commands go to ``hostd/<printer>/cmd`` (refusals come back as events);
    :meth:`query` sends a read-only request to ``hostd/<printer>/req`` and waits for
    its reply on ``hostd/<printer>/reply/<token>`` (this source's own token), which
    is subscribed only while :meth:`open_replies` holds it open (a printer's screen).
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
        self.query_timeout = QUERY_TIMEOUT_S
        self._client: Any = None
        self._requests = itertools.count(1)
        # replies: this source's topic level, the printers whose replies are subscribed
        # (and the SUBACK of each on this connection), the requests waiting for one
        self.token = f"tui-{random.getrandbits(48):012x}"
        self._reply_suffix = f"/reply/{self.token}"
        self._replies: dict[str, asyncio.Future[int] | None] = {}
        self._waiting: dict[str, asyncio.Future[dict[str, Any]]] = {}

    def reply_topic(self, printer: str) -> str:
        """The topic ``printer`` answers this source's requests on."""
        return f"hostd/{printer}{self._reply_suffix}"

    def open_replies(self, printer: str) -> None:
        """Subscribe to ``printer``'s replies to this source (again after a reconnect)."""
        if printer not in self._replies:
            self._replies[printer] = None
            self._subscribe_replies(printer)

    def close_replies(self, printer: str) -> None:
        """Unsubscribe from ``printer``'s replies (its screen was closed)."""
        if printer not in self._replies:
            return
        subscribed = self._replies.pop(printer)
        if subscribed is not None and self._client is not None:
            with contextlib.suppress(OSError):
                self._client.unsubscribe(self.reply_topic(printer))

    def _subscribe_replies(self, printer: str) -> None:
        client = self._client
        if client is None:
            return  # subscribed on connect
        try:
            self._replies[printer] = client.subscribe(self.reply_topic(printer), qos=1)
        except OSError:
            self._replies[printer] = None

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
        """Status, events and availability of every printer followed, across reconnects.

        Replies to :meth:`query` arrive on the same connection and are handed to the
        requests waiting for them, never yielded.
        """
        from tui.mqtt_wire import WireClient, WireError

        rng = random.Random()
        failures = 0
        who = self.printer or "+"
        suffix = self._reply_suffix
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
                    for printer in list(self._replies):
                        self._subscribe_replies(printer)
                    async for message in client.messages():
                        if message.topic.endswith(suffix):
                            self._replied(message.payload)
                            continue
                        item = _decode(message.topic, message.payload)
                        if item is not None:
                            yield item
            except WireError as exc:
                yield StatusItem("", Snapshot(state="offline", error=str(exc)))
            finally:
                self._client = None
                self.connected_to = ""
                for printer in self._replies:
                    self._replies[printer] = None
            failures += 1
            # the next node at once after a drop; a growing pause once every node refused
            ceiling = min(10.0, 0.5 * 2 ** max(0, failures // len(self.brokers)))
            await asyncio.sleep(rng.uniform(ceiling / 4, ceiling / 2))
        raise AssertionError("unreachable")  # pragma: no cover

    def _replied(self, payload: bytes) -> None:
        """A reply on this source's topic: to the request waiting for its id, if any."""
        try:
            reply = json.loads(payload)
        except (ValueError, RecursionError):
            return
        if isinstance(reply, dict):
            waiting = self._waiting.get(str(reply.get("id")))
            if waiting is not None and not waiting.done():
                waiting.set_result(reply)

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
        """Send a read-only request (``layer``, ``estimate``) to ``hostd/<printer>/req`` and
        return its reply; ControlError with the reason when refused, not sent, or not
        answered within ``query_timeout`` seconds (never waits longer)."""
        self.open_replies(printer)
        request_id = f"{self.token}-{next(self._requests)}"
        reply: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._waiting[request_id] = reply
        request = {"req": cmd, **args, "id": request_id, "reply_to": self.reply_topic(printer)}
        try:
            async with asyncio.timeout(self.query_timeout):
                client = self._client
                if client is None:
                    raise ControlError(f"{cmd}: not connected to the broker")
                subscribed = self._replies.get(printer)
                # the SUBACK first: a reply published before it could be lost
                if subscribed is not None and await asyncio.shield(subscribed) >= 0x80:
                    raise ControlError(f"{cmd}: the broker refused this client the topic "
                                       f"{self.reply_topic(printer)}")
                try:
                    await client.publish(f"hostd/{printer}/req", json.dumps(request).encode(),
                                         qos=1)
                except OSError as exc:
                    raise ControlError(f"{cmd}: not sent: {exc}") from exc
                answer = await reply
        except TimeoutError:
            raise ControlError(f"{cmd}: no reply from {printer} in "
                               f"{self.query_timeout:g} s") from None
        finally:
            self._waiting.pop(request_id, None)
        if not answer.get("ok", False):
            raise ControlError(answer.get("error") or f"{cmd} refused")
        return answer


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
