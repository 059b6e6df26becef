"""A daemon's side of the farm: take the next job that fits when the printer is idle, print
it as a job of its own queue, and record the outcome, exactly once.

The rules (see :mod:`hostd.farm.queue` for the JetStream pieces):

- Offers are fetched only when the printer is idle (connected, nothing printing,
  queued or interrupted), all those waiting at once, and the first that fits is
  taken. One that does not fit, or that came while the printer turned busy, is
  given back with a delayed nak; those not looked at, at once.
- Taking is a compare-and-set of the job's entry, waiting -> taken by this
  printer. Only then is the model fetched and queued here, under the name
  ``<job id>.stl``: its G-code, summary and model end in ``done/`` or ``failed/``
  named by the job id, like a dropped file's.
- While it is held, a heartbeat every third of the acknowledgement wait extends
  the offer's lease (``in_progress``) and writes the entry's ``beat`` and layer.
- When the local job ends, the entry becomes printed (done) or failed (the
  slicer's or the printer's reason), and then the offer is acknowledged. A
  failure is final: the job does not go from printer to printer.
- At start, the jobs the bucket says this printer holds are matched with the
  local store: ended ones are recorded, an interrupted one is reported
  ``interrupted`` (resume it here with ``hostd resume``, or give it back with
  ``hostd farm requeue``), one never queued here is queued again (nothing of it
  was printed). A local farm job whose entry is no longer this printer's (given
  back meanwhile) is removed from the local queue, never printed.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import os
import random
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import nats.errors
from nats.aio.msg import Msg
from nats.js import JetStreamContext

from drivers.link.streamer import HALTED, Streamer
from hostd.config import Config, ConfigError, slicing_settings
from hostd.farm.loaded import loaded_material
from hostd.farm.needs import Needs, Station, misfit
from hostd.farm.queue import TRANSIENT, FarmError, FarmQueue, Lost
from hostd.farm.records import HELD, Entry, read_offer
from hostd.jobs.intake import Intake
from hostd.jobs.jobfolder import move
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import FINAL_STATES, JobState, Queued
from hostd.jobs.jobstore import Job, JobStore
from hostd.publishing.status import StatusHub

log = logging.getLogger("hostd.farm")

# how long an offer that does not fit waits before it is offered again (s)
NAK_DELAY_S = 0.5
# how often the printer's declaration is refreshed (s)
DECLARE_EVERY_S = 5.0
# how long one fetch waits for an offer (s)
FETCH_WAIT_S = 1.0
# how many waiting offers one round looks at
OFFERS_AT_ONCE = 32
# how long the sweep for the offers behind the first waits (s)
SWEEP_WAIT_S = 0.1
# what considering an offer that does not fit here gives
GIVEN_BACK = object()
# a local job made from a farm job has this source
SOURCE_PREFIX = "farm:"


class Host(Protocol):
    """What the agent uses of the daemon."""

    config: Config
    store: JobStore
    hub: StatusHub
    intake: Intake
    life: JobLife
    link: Streamer | None
    current: Any  # the print in progress (an ActiveJob), or None

    def queue_changed(self) -> None: ...


@dataclass
class Held:
    """The job this printer holds: its entry as last written, the local job, the offer."""

    entry: Entry
    revision: int
    local: str | None = None
    message: Msg | None = None
    beat: float = 0.0


class FarmAgent:
    """Takes farm jobs for one daemon; ``await run()`` until cancelled."""

    def __init__(self, host: Host) -> None:
        self.host = host
        self.config = host.config
        self.printer = host.config.printer.id
        self.life = host.life
        self.held: Held | None = None
        self.queue: FarmQueue | None = None
        self._wake = asyncio.Event()
        self.lease_s = host.config.farm.ack_wait_s
        self.beat_s = max(0.5, self.lease_s / 3)

    async def run(self) -> None:
        """Connect (again after failures) and serve the farm."""
        loop = asyncio.get_running_loop()

        def wake(_event: dict[str, Any]) -> None:
            loop.call_soon_threadsafe(self._wake.set)

        self.host.hub.listen(wake)
        delay = 1.0
        while True:
            try:
                queue = await FarmQueue.open(self.config.farm, f"hostd-{self.printer}")
            except FarmError as exc:
                log.error("farm: %s; trying again in %.0f s", exc, delay)
                await asyncio.sleep(delay)
                delay = min(delay * 2, 30.0)
                continue
            delay = 1.0
            self.queue = queue
            log.info("farm: connected to %s as printer %s (%s, %g mm nozzle)",
                     queue.client.connected_url.netloc if queue.client.connected_url else "?",
                     self.printer, loaded_material(self.config), self.config.printer.nozzle_mm)
            try:
                await self._serve(queue)
            except FarmError as exc:
                log.error("farm: %s; starting over", exc)
                await asyncio.sleep(1.0)
            except Exception:  # a fault of the farm's must not stop the daemon's printing
                log.exception("farm: internal error; starting over in 5 s")
                await asyncio.sleep(5.0)
            finally:
                self.queue = None
                with contextlib.suppress(Exception):
                    await queue.close()

    async def _serve(self, queue: FarmQueue) -> None:
        await self._reconcile(queue)
        takers = await queue.takers()
        async with asyncio.TaskGroup() as group:
            group.create_task(self._declare_loop(queue), name="farm-declare")
            group.create_task(self._take_loop(queue, takers), name="farm-take")

    # -- the printer's declaration ---------------------------------------------

    def station(self) -> Station:
        """What this printer declares now."""
        bed = self.config.printer.bed
        return Station(self.printer, loaded_material(self.config), self.config.printer.nozzle_mm,
                       (bed[0], bed[1]), self.idle(), time.time())

    async def _declare_loop(self, queue: FarmQueue) -> None:
        while True:
            try:
                await queue.declare(self.station())
            except FarmError as exc:
                log.warning("farm: declaring the printer: %s", exc)
            await asyncio.sleep(DECLARE_EVERY_S)

    def idle(self) -> bool:
        """True when the printer may take a job: connected, nothing printing, queued or
        interrupted, and no farm job held."""
        host = self.host
        link = host.link
        return (self.held is None and link is not None and link.state != HALTED
                and host.current is None and not host.store.queued()
                and not host.store.interrupted())

    # -- taking ----------------------------------------------------------------

    async def _take_loop(self, queue: FarmQueue,
                         takers: JetStreamContext.PullSubscription) -> None:
        while True:
            if self.held is not None:
                await self._follow(queue)
                continue
            if not self.idle():
                log.debug("farm: not taking: printer busy (current %s, queued %d, link %s)",
                          self.host.current, len(self.host.store.queued()),
                          self.host.link.state if self.host.link is not None else None)
                await self._pause(1.0)
                continue
            try:
                await self._take_one(queue, takers)
            except FarmError as exc:
                log.warning("farm: %s", exc)
                await asyncio.sleep(1.0)
                # a take whose answer never came may have been applied: adopt it
                with contextlib.suppress(FarmError):
                    await self._reconcile(queue)

    async def _pause(self, seconds: float) -> None:
        self._wake.clear()
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(seconds):
                await self._wake.wait()

    async def _take_one(self, queue: FarmQueue,
                        takers: JetStreamContext.PullSubscription) -> None:
        """Fetch the offers waiting now and take the first that is waiting, current and
        fits; give the others back.

        All waiting offers are looked at together, not one at a time: JetStream hands
        back an offer given back before a newer one, so a printer that asked for one
        offer at a time would be handed the same misfit over and over and never reach
        the job behind it.
        """
        try:
            messages = await takers.fetch(1, timeout=FETCH_WAIT_S)
        except nats.errors.TimeoutError:
            return
        except TRANSIENT as exc:
            log.debug("farm: fetch: %r", exc)
            await asyncio.sleep(0.5)
            return
        with contextlib.suppress(nats.errors.TimeoutError, *TRANSIENT):
            messages += await takers.fetch(OFFERS_AT_ONCE - 1, timeout=SWEEP_WAIT_S)
        held: Held | None = None
        given_back = False
        for message in messages:
            if held is None:
                outcome = await self._consider(queue, message)
                given_back |= outcome is GIVEN_BACK
                held = outcome if isinstance(outcome, Held) else None
            else:  # not looked at: another printer may take it at once
                await _quietly(message.nak())
        if held is not None:
            self.held = held
            await self._queue_here(queue, held)
        elif given_back:
            # all given back: stay away until they are offered again, so that a printer
            # they fit is the one waiting then (with two printers each holding what the
            # other needs, the one that asked first would otherwise get both every time)
            await asyncio.sleep(NAK_DELAY_S + random.uniform(0.1, 0.9))

    async def _consider(self, queue: FarmQueue, message: Msg) -> Held | object | None:
        """Take one offer if it is waiting, current and fits (its `Held`); give it back if
        it does not fit (`GIVEN_BACK`); settle it otherwise (None)."""
        try:
            job_id, generation = read_offer(message.data)
        except (ValueError, KeyError, TypeError):
            log.warning("farm: an offer that is not one: %r", message.data[:80])
            await _quietly(message.term())
            return None
        try:
            entry, revision = await queue.entry(job_id)
        except FarmError:
            await _quietly(message.ack())  # no such job (its entry was removed)
            return None
        if entry.generation != generation or entry.state != "waiting":
            # taken, printed or failed already, or given back since (a newer offer
            # carries it): this offer is spent
            await _quietly(message.ack())
            return None
        station = self.station()
        why = misfit(Needs.from_dict(entry.needs), station)
        if why is not None or not self.idle():
            log.debug("farm: offer of %s given back: %s", job_id, why or "printer busy")
            await _quietly(message.nak(delay=NAK_DELAY_S))
            return GIVEN_BACK
        mine = entry.but(state="taken", printer=self.printer, reason=None,
                         token=uuid.uuid4().hex, beat=time.time(), lease_s=self.lease_s,
                         layer=-1)
        try:
            revision = await queue.replace(mine, revision)
        except Lost:
            await _quietly(message.ack())  # another printer took it, or it was given back
            return None
        log.info("farm: job %s (%s) taken", entry.id, entry.name)
        return Held(mine, revision, None, message, time.monotonic())

    async def _queue_here(self, queue: FarmQueue, held: Held) -> None:
        """Fetch the model and queue it in this daemon's store as ``<id>.stl``."""
        entry = held.entry
        try:
            settings = slicing_settings(entry.settings, self.config.slicing, "").to_mapping()
        except ConfigError as exc:
            await self._end(queue, held, "failed", f"--set {exc}")
            return
        data = await queue.model(entry)
        name = f"{entry.id}.stl"
        staging = self.config.state.folder / "farm" / "incoming"
        staging.mkdir(parents=True, exist_ok=True)
        staged = staging / name
        await asyncio.to_thread(_write, staged, data)
        store = self.host.store
        job = store.add(name, f"{SOURCE_PREFIX}{entry.id}", str(staged), "stl",
                        hashlib.sha256(data).hexdigest(), settings, size=len(data))
        home = move(staged, self.config.state.folder / "jobs" / job.id / name)
        store.set_path(job.id, str(home))
        held.local = job.id
        log.info("farm: job %s queued here as job %s", entry.id, job.id)
        self.life.publish(Queued(job.id, name))
        self.host.queue_changed()

    # -- holding ---------------------------------------------------------------

    async def _follow(self, queue: FarmQueue) -> None:
        """One step of a held job: heartbeat, and record its end once it ended here."""
        held = self.held
        assert held is not None
        try:
            if held.local is None:
                await self._queue_here(queue, held)
                return
            local = self.host.store.get(held.local)
            if local.state in FINAL_STATES:
                await self._ended(queue, held, local)
                return
            due = time.monotonic() - held.beat >= self.beat_s
            want = "interrupted" if local.state == JobState.INTERRUPTED else "taken"
            changed = want != held.entry.state or local.layer != held.entry.layer
            if (due or changed) and not await self._beat(queue, held, local, want):
                return
        except FarmError as exc:
            log.warning("farm: job %s: %s", held.entry.id, exc)
        await self._pause(min(self.beat_s, 0.5))

    async def _beat(self, queue: FarmQueue, held: Held, local: Job, state: str) -> bool:
        """Extend the lease and record the state and layer; False when the job is no
        longer this printer's (given back meanwhile)."""
        if held.message is not None and state == "taken":
            await _quietly(held.message.in_progress())
        reason = None
        if state == "interrupted":
            reason = (f"interrupted on {self.printer} after layer {local.layer + 1}: resume "
                      f"there with `hostd resume {local.id}` or give it back with "
                      f"`hostd farm requeue {held.entry.id}`")
        entry = held.entry.but(state=state, beat=time.time(), layer=local.layer, reason=reason)
        try:
            held.revision = await queue.replace(entry, held.revision)
        except Lost:
            now, revision = await queue.entry(held.entry.id)
            if now.printer == self.printer and now.token == held.entry.token and \
                    now.state in HELD:
                held.entry, held.revision = now, revision  # a write of ours, retried
                return True
            self._given_back(held, local, now)
            return False
        if state != held.entry.state:
            log.info("farm: job %s %s", held.entry.id, state)
        held.entry = entry.but(updated=held.entry.updated)
        held.beat = time.monotonic()
        return True

    def _given_back(self, held: Held, local: Job, now: Entry) -> None:
        """The entry is no longer ours: drop the local copy unless it is on the bed."""
        self.held = None
        if local.state in (JobState.QUEUED, JobState.INTERRUPTED):
            log.warning("farm: job %s was given back to the queue (%s now); removed here",
                        held.entry.id, now.state)
            self.host.intake.fail(local, "given back to the farm queue", state="cancelled")
            self.host.queue_changed()
        else:
            log.error("farm: job %s is %s by %s now, while this printer is printing it as job "
                      "%s; its outcome here is not recorded in the farm", held.entry.id,
                      now.state, now.printer, local.id)

    async def _ended(self, queue: FarmQueue, held: Held, local: Job) -> None:
        """Record a local job's end: printed when done, else failed with its reason."""
        if local.state == JobState.DONE:
            await self._end(queue, held, "printed", None)
        else:
            reason = local.error or "no reason given"
            if local.state == JobState.CANCELLED:
                reason = f"cancelled on {self.printer}: {reason}"
            await self._end(queue, held, "failed", reason)

    async def _end(self, queue: FarmQueue, held: Held, state: str, reason: str | None) -> None:
        """Record the outcome (printed or failed), then acknowledge the offer."""
        entry = held.entry.but(state=state, reason=reason, beat=time.time())
        try:
            await queue.replace(entry, held.revision)
        except Lost:
            now, _revision = await queue.entry(held.entry.id)
            log.error("farm: job %s ended %s here, but it is %s (%s) in the farm now",
                      held.entry.id, state, now.state, now.printer)
        else:
            log.info("farm: job %s %s%s", held.entry.id, state, f": {reason}" if reason else "")
        if held.message is not None:
            await _quietly(held.message.ack())
        if self.held is held:
            self.held = None
        self._wake.set()

    # -- at start --------------------------------------------------------------

    async def _reconcile(self, queue: FarmQueue) -> None:
        """Match the jobs the farm says this printer holds with the local store."""
        if self.held is not None:
            return  # connected again while holding: the follow loop goes on with it
        farm_jobs = {job.source[len(SOURCE_PREFIX):]: job
                     for job in self.host.store.jobs() if job.source.startswith(SOURCE_PREFIX)}
        for entry, revision in await queue.held_by(self.printer):
            local = farm_jobs.pop(entry.id, None)
            held = Held(entry, revision, local.id if local is not None else None)
            if local is not None and local.state in FINAL_STATES:
                await self._ended(queue, held, local)
                continue
            if self.held is not None:
                log.error("farm: job %s is held by this printer too; left as it is", entry.id)
                continue
            self.held = held
            if local is None:
                log.warning("farm: job %s was taken but never queued here; queued now",
                            entry.id)
            elif local.state == JobState.INTERRUPTED:
                log.warning("farm: job %s (job %s here) was interrupted: resume it with "
                            "`hostd resume %s` or give it back with `hostd farm requeue %s`",
                            entry.id, local.id, local.id, entry.id)
        # local farm jobs not (or no longer) held here: given back while this was away
        for job_id, job in farm_jobs.items():
            if job.state in (JobState.QUEUED, JobState.INTERRUPTED):  # never one printing
                found: Entry | None = None
                with contextlib.suppress(FarmError):
                    found, _revision = await queue.entry(job_id)
                if found is None or found.printer != self.printer or found.state not in HELD:
                    log.warning("farm: job %s is not this printer's any more; job %s removed "
                                "here", job_id, job.id)
                    self.host.intake.fail(job, "given back to the farm queue",
                                          state="cancelled")
                    self.host.queue_changed()


async def _quietly(action: Any) -> None:
    """Answer an offer; an answer lost with the connection is the lease's to settle."""
    with contextlib.suppress(nats.errors.Error, asyncio.TimeoutError):
        await action


def _write(path: Path, data: bytes) -> None:
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
