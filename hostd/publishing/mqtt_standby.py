"""A second, idle MQTT connection that carries the printer's status while the bridge fails over.

With more than one broker in ``mqtt.hosts`` (the nodes of a cluster), the bridge
keeps this link open to a broker other than the one its session is on. When the
session drops (its node stopped or died), the link publishes the newest status
at once, and again at each status interval, until a session is up again. It
publishes at QoS 0 and not retained: a nats cluster delivers such a message at
once, where a new session, a QoS 1 message and a retained one each wait for the
JetStream stream that keeps them (``$MQTT_sess``, ``$MQTT_msgs``,
``$MQTT_rmsgs``) while the streams the dead node led elect new leaders (seconds
after a node is killed: up to 11.7 s measured, ``docs/benchmarks.md``). The
retained status is the session's again once it is back. Commands, events and
``online`` stay on the session; the link subscribes to nothing and has no last
will.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
from collections.abc import Callable
from typing import Protocol

import aiomqtt

from drivers.link.backoff import Backoff
from drivers.link.tasks import cancel_requests, raise_if_cancelled_since
from hostd.api import Snapshot
from hostd.publishing.mqtt_calls import publish

log = logging.getLogger(__name__)

Broker = tuple[str, int]


class SessionView(Protocol):
    """What the link reads of the bridge's session (``hostd.publishing.mqtt.MqttBridge``)."""

    connected: asyncio.Event
    broker: Broker | None  # the broker of the current or last session
    session_changed: asyncio.Event  # set whenever a session starts or ends


class StandbyLink:
    """Keeps a connection to a broker the session is not on, and publishes the status
    (QoS 0, not retained, once an interval) while the session is down.

    ``run()`` lasts until cancelled; it opens the link once the first session is up.
    """

    def __init__(self, brokers: list[Broker], client: Callable[[str, int], aiomqtt.Client],
                 topic: str, session: SessionView, newest: Callable[[], Snapshot],
                 interval_s: float, backoff: Backoff, rng: random.Random) -> None:
        self._brokers = brokers
        self._client = client
        self._topic = topic
        self._session = session
        self._newest = newest
        self._interval = interval_s
        self._backoff = backoff
        self._rng = rng
        self.broker: Broker | None = None  # the link's broker, while it is up
        self.published = 0  # statuses it carried

    async def run(self) -> None:
        """Stay connected to a broker other than the session's, reconnecting with backoff."""
        await self._session.connected.wait()
        attempt = tried = 0
        while True:
            others = [b for b in self._brokers if b != self._session.broker] or self._brokers
            host, port = others[tried % len(others)]
            tried += 1
            asked = cancel_requests()
            linked = False
            try:
                async with self._client(host, port) as client:
                    linked = True
                    self.broker = (host, port)
                    log.info("MQTT standby link to %s:%s", host, port)
                    attempt = 0
                    async with asyncio.TaskGroup() as group:
                        group.create_task(self._watch(client), name="mqtt-standby-watch")
                        group.create_task(self._serve(client, (host, port)),
                                          name="mqtt-standby")
            except* (aiomqtt.MqttError, OSError) as group:
                log.info("MQTT standby link to %s:%s lost or refused: %s", host, port,
                          group.exceptions[0])
            except* _Moved:
                pass  # the session came onto this broker: the link goes to another one
            finally:
                self.broker = None
            if not linked:  # refused while connecting: a cancellation lost there still counts
                raise_if_cancelled_since(asked)
            await asyncio.sleep(self._backoff.delay(attempt // len(self._brokers), self._rng))
            attempt += 1

    @staticmethod
    async def _watch(client: aiomqtt.Client) -> None:
        """Fail as soon as the connection drops (nothing is subscribed: nothing comes)."""
        async for _message in client.messages:
            pass

    async def _serve(self, client: aiomqtt.Client, broker: Broker) -> None:
        """Idle while the session is up on another broker; carry the status while it is down."""
        session = self._session
        carrying = False
        while True:
            session.session_changed.clear()
            if session.connected.is_set():
                if session.broker == broker:
                    raise _Moved
                carrying = False
                await session.session_changed.wait()
                continue
            await publish(client, self._topic, self._newest().to_json(), qos=0)
            self.published += 1
            if not carrying:
                log.info("MQTT status carried by the standby link to %s:%s", *broker)
                carrying = True
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self._interval):
                    await session.session_changed.wait()


class _Moved(Exception):
    """The session is now on the link's broker."""
