"""The MQTT bridge: status, events and availability out; guarded commands and read-only
requests in (design.md topics; the requests: :mod:`hostd.publishing.mqtt_requests`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import random
import ssl
import time
from collections import deque
from dataclasses import dataclass
from functools import partial
from typing import Any, Protocol

import aiomqtt

from drivers.link.backoff import Backoff  # the one reconnect policy (also the printer link's)
from drivers.link.tasks import cancel_requests, raise_if_cancelled_since
from hostd.api import Snapshot
from hostd.publishing.homeassistant import HA_STATUS_TOPIC, DeviceTopics, discovery_messages
from hostd.publishing.mqtt_calls import publish, subscribe
from hostd.publishing.mqtt_requests import RequestDesk
from hostd.publishing.mqtt_standby import StandbyLink
from hostd.publishing.status import CommandError, Controller, StatusHub

log = logging.getLogger(__name__)

# The commands MQTT may carry (design.md); nothing else, and never raw G-code.
MQTT_COMMANDS = (
    "pause", "resume", "cancel", "resume_job", "cancel_object", "restore_object", "set",
    "emergency_stop",
)
MAX_COMMAND_BYTES = 64 * 1024
EVENT_BUFFER = 1000  # events kept while the broker is unreachable (oldest dropped)
INCOMING_BUFFER = 1000  # messages received and not read yet (a flood's further ones dropped)
# A broker that has not answered a CONNECT, or acknowledged a message, within this is
# failed over (the next of mqtt.hosts). Not 10 s: a nats node whose JetStream streams lost
# their leader (a node killed beside it) answers within its own 4 s or not at all.
ACK_TIMEOUT_S = 5.0


class MqttSettings(Protocol):
    """The ``[mqtt]`` section as the bridge reads it (``hostd.config.MqttConfig``)."""

    enabled: bool
    host: str
    port: int
    username: str
    password: str
    tls: bool
    ca_file: str
    allow_commands: bool
    homeassistant: bool
    keepalive: int

    @property
    def brokers(self) -> tuple[tuple[str, int], ...]:
        """(host, port) of each broker to try in turn (``mqtt.hosts``, else host and port)."""
        ...


class ExtraPublisher(Protocol):
    """Publishes more retained topics on each session (``mqtt_extras.MqttExtras``)."""

    async def publish(self, client: aiomqtt.Client) -> None: ...


class MqttSetupError(ValueError):
    """The MQTT settings cannot work (for example an unreadable CA file)."""


@dataclass(frozen=True)
class Topics:
    """The topics of one printer."""

    online: str
    status: str
    event: str
    cmd: str

    @classmethod
    def for_printer(cls, printer_id: str) -> Topics:
        if not printer_id or any(ch in printer_id for ch in "/#+\0"):
            raise MqttSetupError(f"printer id {printer_id!r} cannot be part of an MQTT topic")
        base = f"hostd/{printer_id}"
        return cls(f"{base}/online", f"{base}/status", f"{base}/event", f"{base}/cmd")


class _StatusFeed:
    """The newest snapshot, plus the snapshots that changed ``state`` (published at once)."""

    def __init__(self, first: Snapshot) -> None:
        self.newest = first
        self.version = 0
        self.state_changes: deque[Snapshot] = deque(maxlen=64)
        self.changed = asyncio.Event()

    def put(self, snapshot: Snapshot) -> None:
        if snapshot.state != self.newest.state:
            self.state_changes.append(snapshot)
        self.newest = snapshot
        self.version += 1
        self.changed.set()


class _EventFeed:
    """Events waiting to be published, kept across reconnects (bounded)."""

    def __init__(self) -> None:
        self.items: deque[dict[str, Any]] = deque(maxlen=EVENT_BUFFER)
        self.changed = asyncio.Event()

    def put(self, item: dict[str, Any]) -> None:
        self.items.append(item)
        self.changed.set()


def refusal(cmd: Any, reason: str, request_id: Any = None) -> dict[str, Any]:
    """The ``error`` event that answers a refused MQTT command."""
    item: dict[str, Any] = {"event": "error", "cmd": cmd, "reason": reason, "ts": time.time()}
    if request_id is not None:
        item["id"] = request_id
    return item


def tls_context(settings: MqttSettings) -> ssl.SSLContext | None:
    """The TLS context for ``settings`` (None without TLS); ``ca_file`` adds a trusted CA."""
    if not settings.tls:
        return None
    try:
        return ssl.create_default_context(cafile=settings.ca_file or None)
    except (OSError, ssl.SSLError) as exc:
        raise MqttSetupError(f"mqtt.ca_file: cannot load {settings.ca_file!r}: {exc}") from exc


class MqttBridge:
    """Publishes the hub's status and events to a broker, carries allowed commands back
    and answers read-only requests (:attr:`requests`).

    ``run()`` lasts until cancelled. It never blocks the hub: it reads
    ``hub.snapshots()`` and ``hub.events()``, which drop old snapshots for a
    slow reader, and keeps reconnecting with jittered exponential backoff
    while the broker is away. On cancellation it publishes ``offline`` itself
    (a clean disconnect does not fire the last will). With several brokers, a
    standby link to another one carries the status while the session fails over
    (:class:`hostd.publishing.mqtt_standby.StandbyLink`).
    """

    def __init__(
        self,
        settings: MqttSettings,
        printer_id: str,
        hub: StatusHub,
        controller: Controller,
        *,
        status_interval_s: float = 1.0,
        backoff: Backoff | None = None,
        rng: random.Random | None = None,
        extras: ExtraPublisher | None = None,
    ) -> None:
        self._settings = settings
        self._printer_id = printer_id
        self._hub = hub
        self._controller = controller
        self._interval = status_interval_s
        self._backoff = backoff or Backoff()
        self._rng = rng or random.Random()
        self._extras = extras
        self.topics = Topics.for_printer(printer_id)
        self._tls = tls_context(settings)
        self._status = _StatusFeed(hub.current)
        self._events = _EventFeed()
        self.requests = RequestDesk(printer_id, controller)  # hostd/<id>/req
        # set while a session is up: connected, announced and subscribed
        self.connected = asyncio.Event()
        self.session_changed = asyncio.Event()  # set whenever a session starts or ends
        self.broker: tuple[str, int] | None = None  # the broker of the current or last session
        self.standby: StandbyLink | None = None  # with several brokers: carries the status
        if len(set(settings.brokers)) > 1:  # while a failover is under way
            self.standby = StandbyLink(
                list(settings.brokers), lambda host, port: self._client(host, port, True),
                self.topics.status, self, lambda: self._status.newest, status_interval_s,
                self._backoff, self._rng)

    async def run(self) -> None:
        """Bridge until cancelled; returns at once when MQTT is not enabled."""
        if not self._settings.enabled:
            return
        self._status = _StatusFeed(self._hub.current)
        async with asyncio.TaskGroup() as group:
            group.create_task(self._collect_status(), name="mqtt-collect-status")
            group.create_task(self._collect_events(), name="mqtt-collect-events")
            group.create_task(self._stay_connected(), name="mqtt-connection")
            if self.standby is not None:
                group.create_task(self.standby.run(), name="mqtt-standby-link")

    async def _collect_status(self) -> None:
        async for snapshot in self._hub.snapshots():
            self._status.put(snapshot)

    async def _collect_events(self) -> None:
        async for item in self._hub.events():
            self._events.put(item)

    def _client(self, host: str, port: int, standby: bool = False) -> aiomqtt.Client:
        """The session's client (with the last will), or the standby link's (without)."""
        settings = self._settings
        return aiomqtt.Client(
            host,
            port,
            username=settings.username or None,
            password=settings.password or None,
            identifier=f"hostd-{self._printer_id}" + ("-standby" if standby else ""),
            will=None if standby else aiomqtt.Will(self.topics.online, "offline", qos=1,
                                                   retain=True),
            keepalive=settings.keepalive,
            tls_context=self._tls,
            timeout=ACK_TIMEOUT_S,
            max_queued_incoming_messages=INCOMING_BUFFER,
        )

    async def _stay_connected(self) -> None:
        """Connect, run a session, and on a drop fail over to the next broker of the list.

        After a session that was up, the next broker is tried after a short jittered
        pause (the first backoff step); while none answers, the pause grows once per
        round of the whole list.
        """
        brokers = list(self._settings.brokers)
        index = attempt = 0
        while True:
            host, port = brokers[index % len(brokers)]
            asked = cancel_requests()
            had_session = False
            try:
                async with self._client(host, port) as client:
                    log.info("MQTT connected to %s:%s", host, port)
                    self.broker = (host, port)
                    try:
                        await self._session(client)
                    except asyncio.CancelledError:
                        await self._say_offline(client)
                        raise
            except* (aiomqtt.MqttError, OSError) as group:
                log.warning("MQTT connection to %s:%s lost or refused: %s",
                            host, port, group.exceptions[0])
            except* Exception:  # a bridge bug must not stop the printer: log and reconnect
                log.exception("MQTT bridge failed; reconnecting")
            finally:
                if self.connected.is_set():  # a full session: start the backoff over
                    had_session = True
                    attempt = 0
                    self.connected.clear()
                    self.session_changed.set()
            if not had_session:
                # refused while connecting: aiomqtt waits for the broker's answer with
                # asyncio.wait_for, which on 3.11 loses a cancellation that comes with a
                # refusal, and the bridge would retry for ever after being stopped (no
                # task group of ours ran yet, so the task's count is exact here)
                raise_if_cancelled_since(asked)
            delay = self._backoff.delay(attempt // len(brokers), self._rng)
            attempt += 1
            index += 1
            await asyncio.sleep(delay)

    async def _say_offline(self, client: aiomqtt.Client) -> None:
        """Publish the retained ``offline`` before a clean disconnect (best effort, bounded)."""
        with contextlib.suppress(aiomqtt.MqttError, TimeoutError):
            async with asyncio.timeout(2.0):
                await publish(client, self.topics.online, "offline", qos=1, retain=True)

    async def _session(self, client: aiomqtt.Client) -> None:
        """One connection: the newest status, subscribe, announce, then publish and listen
        until it drops.

        The status goes first: after a failover it is what every fleet view waits for,
        and a cluster node may hold a client's later packets behind a subscription for
        seconds (nats, while its JetStream streams elect new leaders). Commands and
        requests are subscribed before ``online`` is published, so a client that sees
        ``online`` can send one at once.
        """
        feed = self._status
        feed.state_changes.clear()
        sent_version = feed.version
        await self._send_status(client, feed.newest)
        await subscribe(client, self.topics.cmd, qos=1)
        await subscribe(client, self.requests.topic, qos=1)
        await publish(client, self.topics.online, "online", qos=1, retain=True)
        if self._settings.homeassistant:
            await subscribe(client, HA_STATUS_TOPIC, qos=1)
            await self._announce(client)
        self.connected.set()
        self.session_changed.set()
        async with asyncio.TaskGroup() as group:
            group.create_task(self._publish_status(client, sent_version),
                              name="mqtt-publish-status")
            group.create_task(self._publish_events(client), name="mqtt-publish-events")
            group.create_task(self._listen(client), name="mqtt-commands")
            group.create_task(self.requests.serve(partial(self._reply, client)),
                              name="mqtt-requests")
            if self._extras is not None:
                group.create_task(self._extras.publish(client), name="mqtt-extras")

    async def _announce(self, client: aiomqtt.Client) -> None:
        """Home Assistant's device discovery (retained); again whenever Home Assistant starts."""
        commands = self._settings.allow_commands and bool(self._settings.username)
        topics = DeviceTopics.for_printer(self._printer_id)
        for topic, payload in discovery_messages(self._printer_id, topics, commands):
            await publish(client, topic, payload, qos=1, retain=True)

    async def _send_status(self, client: aiomqtt.Client, snapshot: Snapshot) -> None:
        await publish(client, self.topics.status, snapshot.to_json(), qos=1, retain=True)

    async def _publish_status(self, client: aiomqtt.Client, sent_version: int) -> None:
        """Retained status after the session's first (``sent_version``): every state change
        at once, other changes at most once an interval."""
        feed = self._status
        loop = asyncio.get_running_loop()
        last = loop.time()
        while True:
            if feed.state_changes:
                snapshot = feed.state_changes.popleft()
                if snapshot is feed.newest:
                    sent_version = feed.version
                await self._send_status(client, snapshot)
                last = loop.time()
                continue
            feed.changed.clear()
            if feed.version == sent_version:
                await feed.changed.wait()
                continue
            delay = last + self._interval - loop.time()
            if delay > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay):
                        await feed.changed.wait()  # a state change cuts the wait short
                continue
            sent_version = feed.version
            await self._send_status(client, feed.newest)
            last = loop.time()

    async def _publish_events(self, client: aiomqtt.Client) -> None:
        """Each hub event as JSON on the event topic, in order; unsent ones survive a drop."""
        feed = self._events
        while True:
            if not feed.items:
                feed.changed.clear()
                await feed.changed.wait()
                continue
            item = feed.items[0]
            await publish(client, self.topics.event, json.dumps(item, default=str), qos=1)
            if feed.items and feed.items[0] is item:
                feed.items.popleft()

    async def _reply(self, client: aiomqtt.Client, topic: str, payload: str) -> None:
        """One answer to a request: QoS 1, never retained (the desk checked the topic)."""
        await publish(client, topic, payload, qos=1, retain=False)

    async def _listen(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            if message.topic.matches(HA_STATUS_TOPIC):
                if message.payload == b"online":
                    await self._announce(client)
                continue
            if message.topic.matches(self.requests.topic):
                unanswerable = self.requests.take(message.payload, retained=message.retain)
                if unanswerable is not None:
                    name, reason, request_id = unanswerable
                    answer = refusal(name, reason, request_id)
                    await publish(client, self.topics.event, json.dumps(answer, default=str),
                                  qos=1)
                await asyncio.sleep(0)  # a flood of requests never holds the event loop
                continue
            if not message.topic.matches(self.topics.cmd):
                continue
            answer = await self.execute(message.payload, retained=message.retain)
            if answer is not None:
                await publish(client, self.topics.event, json.dumps(answer, default=str), qos=1)

    async def execute(self, payload: Any, *, retained: bool = False) -> dict[str, Any] | None:
        """Carry out one command message; the ``error`` event to publish when refused, else None."""
        if retained:
            return refusal(None, "retained command ignored: commands must not be retained")
        if isinstance(payload, bytes | bytearray) and len(payload) > MAX_COMMAND_BYTES:
            return refusal(None, f"command larger than {MAX_COMMAND_BYTES} bytes")
        try:
            request = json.loads(payload)
        except (TypeError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError
            return refusal(None, f"malformed JSON: {exc}")
        except RecursionError:
            return refusal(None, "malformed JSON: nested too deeply")
        if not isinstance(request, dict):
            return refusal(None, 'a command must be a JSON object such as {"cmd": "pause"}')
        cmd = request.get("cmd")
        request_id = request.get("id")
        if not isinstance(cmd, str):
            return refusal(None, 'missing "cmd"', request_id)
        if not self._settings.allow_commands:
            return refusal(cmd, "commands are disabled (mqtt.allow_commands = false)", request_id)
        if not self._settings.username:
            return refusal(cmd, "commands need broker credentials (mqtt.username)", request_id)
        if cmd not in MQTT_COMMANDS:
            return refusal(
                cmd, f"unknown command {cmd!r}; one of {', '.join(MQTT_COMMANDS)}", request_id
            )
        args = {key: value for key, value in request.items() if key not in ("cmd", "id")}
        try:
            await self._controller.handle(cmd, args)
        except CommandError as exc:
            return refusal(cmd, str(exc), request_id)
        except Exception as exc:  # a controller bug must not take the bridge down
            log.exception("MQTT command %s failed", cmd)
            return refusal(cmd, f"internal error: {type(exc).__name__}: {exc}", request_id)
        return None
