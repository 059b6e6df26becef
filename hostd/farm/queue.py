"""The farm queue on JetStream: an offers stream, a jobs bucket, a printers bucket, a models store.

Every piece has three replicas, so that a cluster of three nodes keeps all of it
while one node is down:

- ``HOSTD_FARM`` (subject ``hostd.farm.jobs``), a work-queue stream: one message
  (an *offer*: job id and generation) per job copy, read by every daemon through
  one shared durable pull consumer ``takers``. A daemon that cannot take an offer
  (busy, or the job does not fit its printer) gives it back with a delayed nak; one
  that takes it keeps it unacknowledged while it prints, its lease extended by
  ``in_progress`` heartbeats, and acknowledges it once the print is over. The
  consumer redelivers without limit (``max_deliver = -1``): every "does not fit"
  is a delivery, and a job may wait for its printer for hours.
- ``hostd_farm_jobs``, a key-value bucket: the job's entry (``records.Entry``), the
  one truth about who owns it. A take is a compare-and-set on the entry's revision
  (waiting -> taken by this printer, with a token of this take), so two daemons can
  never both own a job, whatever the stream redelivers: an offer whose entry is no
  longer waiting, or whose generation is older, is acknowledged away unprinted.
- ``hostd_farm_printers``, a key-value bucket: each printer's declaration
  (``needs.Station``), refreshed by its daemon; ``list`` explains a waiting job
  against them.
- ``hostd_farm_models``, an object store: the submitted models, named by SHA-256
  (the copies of a job, and the same file submitted again, share one object).
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import logging
import ssl
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from functools import partial
from typing import Any, TypeVar

import nats
import nats.errors
import nats.js.errors
from nats.aio.client import Client
from nats.js import JetStreamContext, api
from nats.js.kv import KeyValue
from nats.js.object_store import ObjectStore

from hostd.config import FarmConfig
from hostd.farm.model import Refused, footprint
from hostd.farm.needs import Needs, Station, why_waiting
from hostd.farm.records import HELD, Entry, new_job_id, offer

log = logging.getLogger("hostd.farm")

STREAM = "HOSTD_FARM"
SUBJECT = "hostd.farm.jobs"
CONSUMER = "takers"
JOBS_BUCKET = "hostd_farm_jobs"
PRINTERS_BUCKET = "hostd_farm_printers"
MODELS_BUCKET = "hostd_farm_models"
REPLICAS = 3
# a printer's declaration older than this is not counted (its daemon refreshes it
# every few seconds)
STATION_FRESH_S = 30.0
# the window in which JetStream drops a second offer with the same message id
DUPLICATE_WINDOW_S = 120.0

# errors after which the same request may succeed: a node stopped, a stream electing
# its leader, the connection moving to another node
TRANSIENT: tuple[type[BaseException], ...] = (
    nats.errors.TimeoutError, nats.errors.NoRespondersError,
    nats.errors.ConnectionClosedError, nats.errors.ConnectionReconnectingError,
    nats.errors.StaleConnectionError, nats.errors.OutboundBufferLimitError,
    nats.js.errors.ServiceUnavailableError, nats.js.errors.ServerError,
    nats.js.errors.NoStreamResponseError, asyncio.TimeoutError,
)

# JetStream errors no retry mends: replicas asked of a server that is not clustered (a
# cluster short of room, 10023, may be one still starting: that one is retried)
LASTING_CODES = frozenset({10074})

T = TypeVar("T")


class FarmError(RuntimeError):
    """A farm request that cannot be done; the message says why."""


class Lost(FarmError):
    """A compare-and-set found the entry changed by someone else."""


async def retrying(operation: Callable[[], Awaitable[T]], what: str,
                   deadline_s: float = 60.0) -> T:
    """``operation()``, tried again after transient errors for up to ``deadline_s``."""
    delay = 0.1
    give_up = time.monotonic() + deadline_s
    while True:
        try:
            return await operation()
        except TRANSIENT as exc:
            if getattr(exc, "err_code", None) in LASTING_CODES:
                raise
            if time.monotonic() + delay > give_up:
                raise FarmError(f"{what}: the cluster did not answer ({exc!r})") from exc
            log.debug("%s: %r; trying again in %.1f s", what, exc, delay)
            await asyncio.sleep(delay)
            delay = min(delay * 2, 2.0)


@dataclass(frozen=True)
class Listed:
    """One line of ``hostd farm list``: the contract's fields, and the job's name."""

    id: str
    state: str
    printer: str | None
    reason: str | None
    name: str

    def to_dict(self) -> dict[str, Any]:
        """The contract's JSON object (``id``, ``state``, ``printer``, ``reason``) and ``name``."""
        return {"id": self.id, "state": self.state, "printer": self.printer,
                "reason": self.reason, "name": self.name}


def tls_context(config: FarmConfig) -> ssl.SSLContext | None:
    """The TLS context of ``[farm] tls`` (with ``ca_file`` when given), else None."""
    if not config.tls:
        return None
    context = ssl.create_default_context(cafile=config.ca_file or None)
    return context


class FarmQueue:
    """A connection to the farm's stream, buckets and store, and what is done with them."""

    def __init__(self, client: Client, js: JetStreamContext, jobs: KeyValue,
                 printers: KeyValue, models: ObjectStore) -> None:
        self.client = client
        self.js = js
        self.jobs = jobs
        self.printers = printers
        self.models = models

    @classmethod
    async def open(cls, config: FarmConfig, name: str = "hostd-farm",
                   ack_wait_s: float | None = None) -> FarmQueue:
        """Connect to ``config.servers`` and make sure the stream, buckets and store exist
        (created with three replicas when missing). ``ack_wait_s``: the consumer's
        acknowledgement wait when this creates it (``config.ack_wait_s`` by default)."""
        seen: list[BaseException] = []

        async def remember(error: Exception) -> None:
            seen[:] = [error]  # the last one only
            log.debug("farm connection: %r", error)

        # each server is tried a few times at first (a wrong password or a cluster that is
        # down is reported instead of waited on for ever); once connected, the client
        # reconnects without limit
        options: dict[str, Any] = {
            "servers": list(config.servers), "name": name, "connect_timeout": 2,
            "reconnect_time_wait": 0.5, "max_reconnect_attempts": 2,
            "allow_reconnect": True, "error_cb": remember,
        }
        if config.user:
            options["user"] = config.user
            options["password"] = config.password
        context = tls_context(config)
        if context is not None:
            options["tls"] = context
        try:
            client = await nats.connect(**options)
        except (TimeoutError, OSError, nats.errors.Error) as exc:
            cause = seen[-1] if seen else exc
            raise FarmError(f"cannot reach the farm's servers {', '.join(config.servers)}: "
                            f"{cause}") from exc
        client.options["max_reconnect_attempts"] = -1
        try:
            js = client.jetstream(timeout=5)
            jobs, printers, models = await retrying(
                lambda: _ensure(js, ack_wait_s or config.ack_wait_s), "setting up the farm")
        except nats.js.errors.APIError as exc:  # e.g. three replicas on fewer nodes
            await client.close()
            raise FarmError(f"the farm's stream, buckets and store ({REPLICAS} replicas each) "
                            f"cannot be set up: {exc.description or exc}") from exc
        except BaseException:
            await client.close()
            raise
        return cls(client, js, jobs, printers, models)

    async def close(self) -> None:
        """Flush and close the connection (closed at once when it cannot flush in 2 s)."""
        try:
            async with asyncio.timeout(2.0):  # a cluster out of reach does not hold a stop
                await self.client.drain()
        except (TimeoutError, nats.errors.Error):
            await self.client.close()

    # -- submitting ------------------------------------------------------------

    async def submit(self, name: str, data: bytes, copies: int = 1,
                     settings: dict[str, Any] | None = None, needs: Needs | None = None,
                     max_bytes: int = 50_000_000) -> list[str]:
        """Store the model once and offer ``copies`` jobs of it; returns their ids.

        Refused (not an STL, over ``max_bytes``) before anything is stored. The
        model's footprint raises the bed the jobs need (a printer whose bed cannot
        hold it is not offered the job).
        """
        if copies < 1:
            raise Refused("--copies must be at least 1")
        width, depth = footprint(name, data, max_bytes)
        needs = (needs or Needs()).at_least_bed(round(width, 2), round(depth, 2))
        digest = hashlib.sha256(data).hexdigest()
        await self._store_model(digest, data)
        now = time.time()
        ids = []
        for _copy in range(copies):
            entry = Entry(id=new_job_id(), name=name, model=digest, size=len(data),
                          settings=dict(settings or {}), needs=needs.to_dict(), submitted=now,
                          updated=now)
            await self._create(entry)
            await self.offer(entry)
            ids.append(entry.id)
        return ids

    async def _create(self, entry: Entry) -> None:
        """Record a new job's entry (a create whose answer was lost and that was applied
        counts as done)."""
        data = entry.to_bytes()
        try:
            await retrying(partial(self.jobs.create, entry.id, data), f"recording job {entry.id}")
        except nats.js.errors.KeyWrongLastSequenceError:
            now, _revision = await self.entry(entry.id)
            if now.to_bytes() != data:
                raise FarmError(f"job id {entry.id} is taken already") from None

    async def _store_model(self, digest: str, data: bytes) -> None:
        async def present() -> bool:
            try:
                info = await self.models.get_info(digest)
            except nats.js.errors.ObjectNotFoundError:
                return False
            return int(info.size or 0) == len(data)

        if await retrying(present, "looking for the model"):
            return
        await retrying(lambda: self.models.put(digest, data), "storing the model")

    async def offer(self, entry: Entry) -> None:
        """Publish the offer of ``entry``'s generation (a repeat within two minutes is
        dropped by its message id)."""
        await retrying(
            lambda: self.js.publish(SUBJECT, offer(entry.id, entry.generation), stream=STREAM,
                                    headers={"Nats-Msg-Id": f"{entry.id}.{entry.generation}"}),
            f"offering job {entry.id}")

    async def model(self, entry: Entry) -> bytes:
        """The job's model, checked against its SHA-256."""
        result = await retrying(lambda: self.models.get(entry.model), "fetching the model")
        data = bytes(result.data or b"")
        if hashlib.sha256(data).hexdigest() != entry.model:
            raise FarmError(f"job {entry.id}: the stored model does not match its SHA-256")
        return data

    # -- entries ---------------------------------------------------------------

    async def entry(self, job_id: str) -> tuple[Entry, int]:
        """The job's entry and its revision; FarmError when there is no such job."""
        try:
            found = await retrying(lambda: self.jobs.get(job_id), f"reading job {job_id}")
        except (nats.js.errors.KeyNotFoundError, nats.js.errors.InvalidKeyError):
            raise FarmError(f"no farm job {job_id!r}") from None
        assert found.value is not None
        assert found.revision is not None
        return Entry.from_bytes(found.value), found.revision

    async def replace(self, entry: Entry, revision: int) -> int:
        """Write ``entry`` if the job is still at ``revision``; returns the new revision.

        Lost when someone else changed it. A write whose answer was lost and that was
        applied (the entry now equals ``entry``) counts as done.
        """
        entry = entry.but(updated=time.time())
        data = entry.to_bytes()
        delay = 0.1
        give_up = time.monotonic() + 60.0
        while True:
            try:
                return await self.jobs.update(entry.id, data, last=revision)
            except nats.js.errors.KeyWrongLastSequenceError:
                now, now_revision = await self.entry(entry.id)
                if now.to_bytes() == data:
                    return now_revision  # our own write, its answer lost on the way
                raise Lost(f"job {entry.id} changed meanwhile (it is {now.state})") from None
            except TRANSIENT as exc:
                if time.monotonic() + delay > give_up:
                    raise FarmError(f"writing job {entry.id}: the cluster did not answer "
                                    f"({exc!r})") from exc
                await asyncio.sleep(delay)
                delay = min(delay * 2, 2.0)

    async def entries(self) -> list[tuple[Entry, int]]:
        """Every job's entry and revision, oldest submission first.

        The keys come from the bucket's stream (its subjects, answered by the stream's
        leader): the client's ``keys()``, a watcher that stops when the server says
        nothing is pending, came back short while the bucket was being written.
        """
        found = []
        keys = await self._keys(JOBS_BUCKET)
        for start in range(0, len(keys), 64):
            batch = await asyncio.gather(*(self._entry_or_none(key)
                                           for key in keys[start:start + 64]))
            found += [item for item in batch if item is not None]
        found.sort(key=lambda item: (item[0].submitted, item[0].id))
        return found

    async def _entry_or_none(self, key: str) -> tuple[Entry, int] | None:
        try:
            return await self.entry(key)
        except FarmError:
            return None  # deleted

    async def _keys(self, bucket: str) -> list[str]:
        """The keys of a bucket, from its stream's subjects."""
        prefix = f"$KV.{bucket}."
        info = await retrying(partial(self.js.stream_info, f"KV_{bucket}",
                                      subjects_filter=f"{prefix}>"), f"listing {bucket}")
        return sorted(subject[len(prefix):] for subject in (info.state.subjects or {}))

    async def listing(self) -> list[Listed]:
        """The queue as ``hostd farm list`` shows it: failures first, then held, waiting
        (with why), printed; a waiting job's reason comes from the printers declared now."""
        stations = await self.stations()
        now = time.time()
        rows = []
        for entry, _revision in await self.entries():
            reason = entry.reason
            if entry.state == "waiting":
                reason = why_waiting(Needs.from_dict(entry.needs),
                                     stations)
            elif entry.state == "taken" and entry.beat and entry.lease_s and \
                    now - entry.beat > entry.lease_s:
                reason = (f"no heartbeat from {entry.printer} for {now - entry.beat:.0f} s: "
                          f"held until its daemon restarts (or `hostd farm requeue --force "
                          f"{entry.id}`)")
            rows.append(Listed(entry.id, entry.state, entry.printer, reason, entry.name))
        order = {"failed": 0, "interrupted": 1, "taken": 2, "waiting": 3, "printed": 4}
        rows.sort(key=lambda row: order.get(row.state, 5))
        return rows

    async def requeue(self, job_id: str, force: bool = False) -> Entry:
        """Give a job back to the queue: a new generation offered, its holder cleared.

        Refused for a printed job, and for one its printer is printing (heartbeat
        within its lease): stop it there first. A taken job whose holder fell silent
        (killed, or cut off from the cluster while it may still be printing) is
        refused too unless ``force``: its daemon reports it interrupted when it
        restarts, and only then is giving it back safe from a second print.
        """
        entry, revision = await self.entry(job_id)
        if entry.state == "printed":
            raise FarmError(f"job {job_id} was printed by {entry.printer}; submit it again "
                            "for another copy")
        silent = time.time() - entry.beat
        if entry.state == "taken" and silent <= max(entry.lease_s, 1.0):
            raise FarmError(f"job {job_id} is being printed by {entry.printer} (heartbeat "
                            f"{silent:.0f} s ago); stop it there first")
        if entry.state == "taken" and not force:
            raise FarmError(f"job {job_id} is held by {entry.printer}, silent for {silent:.0f} s:"
                            f" restart its daemon (it then reports the job interrupted), or "
                            f"requeue --force if that printer will not print it")
        again = entry.but(state="waiting", printer=None, reason=None, token=None, beat=0.0,
                          lease_s=0.0, layer=-1, generation=entry.generation + 1)
        try:
            await self.replace(again, revision)
        except Lost as exc:
            raise FarmError(f"job {job_id} changed while it was requeued; try again") from exc
        await self.offer(again)
        return again

    # -- printers --------------------------------------------------------------

    async def declare(self, station: Station) -> None:
        """Record (refresh) a printer's declaration."""
        data = json.dumps(station.to_dict()).encode()
        await retrying(lambda: self.printers.put(station.printer, data), "declaring the printer")

    async def stations(self) -> list[Station]:
        """The printers declared within the last :data:`STATION_FRESH_S` seconds."""
        found = []
        now = time.time()
        for key in await self._keys(PRINTERS_BUCKET):
            try:
                value = await retrying(partial(self.printers.get, key), "a printer")
            except nats.js.errors.KeyNotFoundError:
                continue
            if value.value:
                station = Station.from_dict(json.loads(value.value))
                if now - station.seen <= STATION_FRESH_S:
                    found.append(station)
        return found

    async def held_by(self, printer: str) -> list[tuple[Entry, int]]:
        """The jobs ``printer`` holds (taken or interrupted)."""
        return [(e, r) for e, r in await self.entries()
                if e.printer == printer and e.state in HELD]

    async def takers(self) -> JetStreamContext.PullSubscription:
        """A pull subscription on the shared ``takers`` consumer."""
        return await retrying(
            lambda: self.js.pull_subscribe_bind(CONSUMER, stream=STREAM), "joining the takers")


async def _ensure(js: JetStreamContext, ack_wait_s: float
                  ) -> tuple[KeyValue, KeyValue, ObjectStore]:
    """The stream, its consumer, the buckets and the store, created when missing."""
    try:
        await js.stream_info(STREAM)
    except nats.js.errors.NotFoundError:
        await js.add_stream(api.StreamConfig(
            name=STREAM, subjects=[SUBJECT], retention=api.RetentionPolicy.WORK_QUEUE,
            storage=api.StorageType.FILE, num_replicas=REPLICAS,
            duplicate_window=DUPLICATE_WINDOW_S))
    try:
        await js.consumer_info(STREAM, CONSUMER)
    except nats.js.errors.NotFoundError:
        await js.add_consumer(STREAM, api.ConsumerConfig(
            durable_name=CONSUMER, ack_policy=api.AckPolicy.EXPLICIT, ack_wait=ack_wait_s,
            max_deliver=-1, filter_subject=SUBJECT, num_replicas=REPLICAS))
    try:
        jobs = await js.key_value(JOBS_BUCKET)
    except nats.js.errors.BucketNotFoundError:
        jobs = await js.create_key_value(api.KeyValueConfig(
            bucket=JOBS_BUCKET, history=5, replicas=REPLICAS, storage=api.StorageType.FILE))
    try:
        printers = await js.key_value(PRINTERS_BUCKET)
    except nats.js.errors.BucketNotFoundError:
        printers = await js.create_key_value(api.KeyValueConfig(
            bucket=PRINTERS_BUCKET, history=1, replicas=REPLICAS, storage=api.StorageType.FILE))
    try:
        models = await js.object_store(MODELS_BUCKET)
    except nats.js.errors.BucketNotFoundError:
        models = await js.create_object_store(MODELS_BUCKET, config=api.ObjectStoreConfig(
            replicas=REPLICAS, storage=api.StorageType.FILE))
    return jobs, printers, models
