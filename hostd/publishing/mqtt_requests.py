"""Read-only requests over MQTT: ``hostd/<printer>/req`` in, each reply on the asker's topic.

A request is one JSON object ``{"req": NAME, "id": ..., "reply_to": TOPIC, ...args}``.
MQTT 3.1.1 has no response topic of its own, so the asker names one, and it must be
``hostd/<printer>/reply/<client>``: ``<client>`` one topic level of 1 to 64 letters,
digits, ``-`` or ``_``. The daemon publishes nowhere else: a request with any other
``reply_to`` is not answered, and the refusal goes to the printer's ``event`` topic
(at most one a second).

Only :data:`MQTT_REQUESTS` are taken, with the control socket's handlers and
arguments (:mod:`hostd.printing.controller`); the reply is the control socket's reply object
(``{"reply", "ok", "id", "error", ...}``), published on ``reply_to`` with QoS 1, not
retained. They need neither ``mqtt.allow_commands`` nor credentials: commands, which
change the print, stay on ``hostd/<printer>/cmd``.

The work is bounded. A request message is at most :data:`MAX_REQUEST_BYTES`, a reply
at most :data:`MAX_REPLY_BYTES` (under the 1 MiB a nats-server carries by default;
a larger one is refused with a hint). At most :data:`MAX_QUEUED` requests wait, at
most :data:`MAX_PER_CLIENT` for one reply topic, and they are answered one at a
time (a ``layer`` or ``estimate`` slices in a thread beside the printer's layers):
a client that floods requests is told ``busy``, and the status, events and commands
go on as before.
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
import re
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from hostd.api import accepted, refused
from hostd.publishing.status import CommandError, Controller

log = logging.getLogger(__name__)

MQTT_REQUESTS = ("layer", "estimate")  # read-only: they change nothing of the print
MAX_REQUEST_BYTES = 16 * 1024
MAX_REPLY_BYTES = 900 * 1024
MAX_QUEUED = 16
MAX_PER_CLIENT = 4
UNANSWERABLE_EVERY_S = 1.0  # refusals of requests without a usable reply topic, at most
_CLIENT = re.compile(r"[A-Za-z0-9_-]{1,64}")

# (the request's name or None, the reason, its id): a refusal for the event topic
Unanswerable = tuple[str | None, str, Any]


@dataclass(frozen=True)
class _Request:
    name: str
    request_id: Any
    reply_to: str
    args: dict[str, Any]


class RequestDesk:
    """Takes the request messages of one printer and answers them one at a time.

    :meth:`take` (called by the bridge's listener for each message on
    :attr:`topic`) never waits; :meth:`serve` (one task per MQTT session)
    publishes the answers and the refusals. Requests waiting survive a reconnect.
    """

    def __init__(self, printer_id: str, controller: Controller) -> None:
        self.topic = f"hostd/{printer_id}/req"
        self.prefix = f"hostd/{printer_id}/reply/"
        self._controller = controller
        self._queue: collections.deque[_Request] = collections.deque()
        # (reply topic, reply) refused at once; the oldest dropped when a flood fills it
        self._refusals: collections.deque[tuple[str, dict[str, Any]]] = collections.deque(
            maxlen=2 * MAX_QUEUED)
        self._waiting: collections.Counter[str] = collections.Counter()  # per reply topic
        self._queued = asyncio.Event()  # set when a request is queued
        self._refusal = asyncio.Event()  # set when a refusal is waiting
        self._refused_at = -UNANSWERABLE_EVERY_S  # when an unanswerable one was last refused

    def reply_topic_ok(self, topic: Any) -> bool:
        """Whether ``topic`` is one this printer may answer on (``<prefix><client>``)."""
        return (isinstance(topic, str) and topic.startswith(self.prefix)
                and _CLIENT.fullmatch(topic[len(self.prefix):]) is not None)

    def take(self, payload: Any, *, retained: bool = False) -> Unanswerable | None:
        """Queue one request message, or its refusal for the asker; never waits.

        Returns the refusal to publish on the ``event`` topic when the message names
        no reply topic the daemon may publish on (nothing is answered then; at most one
        such refusal a second), else None.
        """
        if not isinstance(payload, bytes | bytearray | str):
            return self._unanswerable(None, "a request must be a JSON object", None)
        if len(payload) > MAX_REQUEST_BYTES:
            return self._unanswerable(None, f"request larger than {MAX_REQUEST_BYTES} bytes", None)
        try:
            request = json.loads(payload)
        except (TypeError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError
            return self._unanswerable(None, f"malformed request JSON: {exc}", None)
        except RecursionError:
            return self._unanswerable(None, "malformed request JSON: nested too deeply", None)
        if not isinstance(request, dict):
            return self._unanswerable(
                None, 'a request must be a JSON object such as {"req": "layer", ...}', None)
        name, request_id, reply_to = request.get("req"), request.get("id"), request.get("reply_to")
        shown = name if isinstance(name, str) else None
        if not self.reply_topic_ok(reply_to):
            return self._unanswerable(
                shown, f'"reply_to" must be {self.prefix}<client> (<client>: 1 to 64 letters, '
                       "digits, - or _); not answered", request_id)
        if retained:
            self._refuse(reply_to, shown, request_id,
                         "retained request ignored: requests must not be retained")
        elif shown is None:
            self._refuse(reply_to, None, request_id, 'missing "req"')
        elif shown not in MQTT_REQUESTS:
            self._refuse(reply_to, shown, request_id,
                         f"unknown request {shown!r}; one of {', '.join(MQTT_REQUESTS)} "
                         "(commands go to the cmd topic)")
        elif len(self._queue) >= MAX_QUEUED or self._waiting[reply_to] >= MAX_PER_CLIENT:
            self._refuse(reply_to, shown, request_id,
                         "busy: too many requests waiting; ask again later")
        else:
            args = {k: v for k, v in request.items() if k not in ("req", "id", "reply_to")}
            self._queue.append(_Request(shown, request_id, reply_to, args))
            self._waiting[reply_to] += 1
            self._queued.set()
        return None

    def _unanswerable(self, name: str | None, reason: str, request_id: Any
                      ) -> Unanswerable | None:
        """The refusal for the event topic, at most one each UNANSWERABLE_EVERY_S (a flood
        of them is logged, not published to every dashboard)."""
        now = time.monotonic()
        if now - self._refused_at < UNANSWERABLE_EVERY_S:
            log.debug("MQTT request refused (not published): %s", reason)
            return None
        self._refused_at = now
        return name, reason, request_id

    def _refuse(self, reply_to: str, name: str | None, request_id: Any, reason: str) -> None:
        self._refusals.append((reply_to, refused(name, request_id, reason)))
        self._refusal.set()

    @property
    def waiting(self) -> int:
        """Requests queued and not answered yet."""
        return len(self._queue)

    async def serve(self, publish: Callable[[str, str], Awaitable[None]]) -> None:
        """Publish answers and refusals (``publish(topic, payload)``) until cancelled; a
        refusal never waits behind a request being answered."""
        async with asyncio.TaskGroup() as group:
            group.create_task(self._answers(publish), name="mqtt-request-answers")
            group.create_task(self._refused(publish), name="mqtt-request-refusals")

    async def _answers(self, publish: Callable[[str, str], Awaitable[None]]) -> None:
        while True:
            if not self._queue:
                self._queued.clear()
                await self._queued.wait()
                continue
            request = self._queue.popleft()
            try:
                text = await self._answer(request)
            finally:
                self._waiting[request.reply_to] -= 1
                if self._waiting[request.reply_to] <= 0:
                    del self._waiting[request.reply_to]
            await publish(request.reply_to, text)

    async def _refused(self, publish: Callable[[str, str], Awaitable[None]]) -> None:
        while True:
            if not self._refusals:
                self._refusal.clear()
                await self._refusal.wait()
                continue
            topic, reply = self._refusals.popleft()
            await publish(topic, _encode(reply))

    async def _answer(self, request: _Request) -> str:
        """The reply to one request, encoded (a refusal when it would be too large)."""
        name, request_id = request.name, request.request_id
        try:
            result = await self._controller.handle(name, request.args)
        except CommandError as exc:
            reply = refused(name, request_id, str(exc))
        except Exception as exc:  # a handler's bug must not take the bridge down
            log.exception("MQTT request %s failed", name)
            reply = refused(name, request_id, f"internal error: {type(exc).__name__}: {exc}")
        else:
            reply = accepted(name, request_id, dict(result or {}))
        text = _encode(reply)
        if len(text) > MAX_REPLY_BYTES:
            text = _encode(refused(name, request_id, (
                f"the reply would be {len(text)} bytes, more than the {MAX_REPLY_BYTES} "
                'sent over MQTT: ask with a larger "tolerance" or a smaller "field"')))
        return text


def _encode(reply: dict[str, Any]) -> str:
    return json.dumps(reply, separators=(",", ":"), default=str)
