"""The just-in-time runner: streams a job layer by layer while later layers are sliced."""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import time
from collections.abc import Callable, Hashable, Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NamedTuple, Protocol

from drivers.link.acks import Ack, AckChannel
from drivers.link.protocol import strip_comment
from drivers.link.streamer import LinkError, StreamCancelled
from drivers.link.tasks import cancel_and_wait
from drivers.link.transport import TransportError
from hostd.api import JobStatus, duration, layer_in_progress
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import JobError, JobState, LayerDone, Paused, Resumed
from hostd.jobs.jobstore import Job
from hostd.printing.checkpoints import Checkpoint, CheckpointWriter
from hostd.printing.eta import EtaModel
from hostd.printing.reentry import reentry_moves
from hostd.printing.sources import LayerSource

log = logging.getLogger("hostd.printing.runner")

PREAMBLE = -1  # mark of the start (or resume) block, before layer 0
ENDING = -2  # mark of the end block
WAIT_POLL_S = 0.5  # while a layer is not ready, how often what it waits for is looked at


class Link(Protocol):
    """What the runner needs of the printer connection (a ``drivers.link.streamer.Streamer``):
    tagged sends, one channel of acknowledgements, and the link's own pause and cancel."""

    async def send(self, command: str, tag: Hashable | None = None) -> int: ...

    async def send_many(self, commands: Iterable[tuple[str, Hashable | None]]) -> int | None: ...

    async def drain(self) -> None: ...

    def acknowledgements(self) -> AbstractContextManager[AckChannel]: ...

    async def pause(self, park: Iterable[str] | None = None, *, settle: bool = True) -> None: ...

    async def resume(self, unpark: Iterable[str] | None = None) -> None: ...

    async def cancel(self, end_gcode: Iterable[str] = (), *, settle: bool = True) -> None: ...

    async def interrupt_wait(self) -> None: ...


class JobLine(NamedTuple):
    """The tag of one job line: ``seq`` job lines sent before it in this run, its
    ``layer`` (or PREAMBLE, ENDING) and its command ``index`` in that layer (counting
    the commands a resume skips)."""

    seq: int
    layer: int
    index: int


@dataclass(frozen=True)
class Park:
    """Commands around a pause: lift the nozzle off the part, and put it back."""

    park: tuple[str, ...] = ()
    unpark: tuple[str, ...] = ()


def park_moves(lift_mm: float) -> Park:
    """A relative Z lift of ``lift_mm`` (none when 0), for jobs with relative extrusion."""
    if lift_mm <= 0:
        return Park()
    lift = f"{lift_mm:.2f}"
    return Park(
        park=("G91", f"G1 Z{lift} F600", "G90", "M83"),
        unpark=("G91", f"G1 Z-{lift} F600", "G90", "M83"),
    )


class JobCancelled(Exception):
    """The job was cancelled by a command."""


@dataclass(frozen=True)
class _Mark:
    """A point in the stream: once the job line tagged ``seq`` is acknowledged, ``layer``
    is complete (``seq`` -1: at once, nothing of the run was sent before it)."""

    seq: int
    layer: int
    offset: int


class JobRunner:
    """Prints one job: preamble, layers ``first..n-1`` and ending, checkpointing as acknowledged.

    Lines go to the printer through ``link``, each tagged with a :class:`JobLine`,
    and, with their comments, to ``output`` (the job's G-code file being written).
    Acknowledgements come back through the link's channel with their tags, read by a
    task of the run (:meth:`on_ack`), which hands the newest checkpoint (last complete
    layer, lines acknowledged, commands of the next layer acknowledged, bytes of
    ``output``) to a :class:`~hostd.printing.checkpoints.CheckpointWriter`, which makes it
    durable in its own thread. ``skip`` commands of layer ``first`` are written to
    ``output`` but not sent (a resume within that layer): in their place go the moves
    that bring the nozzle back to where they left it, sent untagged. Pause and cancel
    are the link's (:meth:`Streamer.pause`, :meth:`Streamer.cancel`): the runner
    chooses the park moves and the end G-code and keeps the job's state.
    """

    def __init__(
        self,
        job: Job,
        source: LayerSource,
        link: Link,
        life: JobLife,
        output: IO[str],
        first: int,
        write_preamble: bool,
        park: Park | None = None,
        skip: int = 0,
        end_gcode: tuple[str, ...] = (),
    ) -> None:
        """``life``: the one writer of the job's state (its print's, see
        :class:`~hostd.printing.activejob.ActiveJob`); ``end_gcode``: sent after the lines in
        flight when the job is cancelled."""
        self.job = job
        self.source = source
        self.link = link
        self.life = life
        self.output = output
        self.first = first
        self.write_preamble = write_preamble
        self.skip = skip
        self.layers = source.layer_count
        self.completed = first - 1
        resumed = first > 0 or skip > 0
        # lines of layer `first` acknowledged before and sent again now are counted once
        self.lines_acked = job.lines_acked - max(0, job.layer_lines - skip) if resumed else 0
        self.state = JobState.SLICING
        self.writer: CheckpointWriter | None = None
        self._marks: collections.deque[_Mark] = collections.deque()
        self._seq = 0  # job lines sent by this run: the next line's JobLine.seq
        self.park = park or Park()
        self.end_gcode = end_gcode
        self._layer_lines = 0  # commands of the layer after `completed` acknowledged
        self._offset = job.gcode_bytes if resumed else 0  # file length through `completed`
        self._parked = False  # the pause in force lifted the nozzle
        self._commands = asyncio.Lock()  # pause and resume, one at a time
        self._cancelled = False
        self._extruded = False  # the printer acknowledged an extruding move of this run
        self._last_seq = -1  # JobLine.seq of the newest job line acknowledged
        self.output_error: str | None = None
        self._started = time.monotonic()
        self._print_started: float | None = None
        self._layers_timed = 0
        self._last_layer_at = 0.0
        self._last_publish = 0.0
        self.streaming_layer = first
        # what a layer not ready yet waits for (None: nothing named), see JobStatus
        self.waiting: Callable[[], str | None] = lambda: None
        self.eta = EtaModel(getattr(source, "schedule", None), self.layers, first)

    # -- commands -------------------------------------------------------------

    async def pause(self) -> None:
        """The link stops after the lines written and lifts the nozzle (once printing);
        returns at once, while the printer empties its buffer."""
        async with self._commands:
            if self.state == JobState.PAUSED or self._cancelled:
                return
            await self._states_written()
            self._parked = self._print_started is not None and bool(self.park.park)
            await self.link.pause(self.park.park if self._parked else (), settle=False)
            self.eta.pause(time.monotonic())
            self._set_state(JobState.PAUSED)
            log.info("job %s %s: paused after layer %d", self.job.id, self.job.name,
                     self.completed + 1)
            self.life.publish(Paused(self.job.id, self.job.name, self.completed))

    async def resume(self) -> None:
        """Put the nozzle back (once acknowledged), and the link sends on where it stopped."""
        async with self._commands:
            if self.state != JobState.PAUSED or self._cancelled:
                return
            await self._states_written()
            await self.link.resume(self.park.unpark if self._parked else ())
            self._parked = False
            self.eta.resume(time.monotonic())
            self._set_state(JobState.PRINTING if self._print_started is not None
                            else JobState.HEATING)
            log.info("job %s %s: resumed", self.job.id, self.job.name)
            self.life.publish(Resumed(self.job.id, self.job.name, self.completed))

    async def cancel(self) -> None:
        """No further line of the job: the link ends any heating wait (``M108``), refuses
        the job's lines and sends ``end_gcode`` after those in flight."""
        if self._cancelled:
            return
        self._cancelled = True
        log.info("job %s %s: cancel requested; the lines in flight end it", self.job.id,
                 self.job.name)
        with contextlib.suppress(LinkError, TransportError):  # a lost link stops the job too
            await self.link.interrupt_wait()
        await self.link.cancel(self.end_gcode, settle=False)

    @property
    def paused(self) -> bool:
        return self.state == JobState.PAUSED

    # -- streaming ------------------------------------------------------------

    async def run(self) -> None:
        """Stream the whole job; returns when every line is acknowledged.

        Raises JobCancelled after :meth:`cancel` (the link then cancelled: the caller
        drains it and calls ``begin_job()``); CancelledError propagates (the daemon
        stopping), leaving the last checkpoint in the store.
        """
        self.writer = CheckpointWriter(self.life.store, self.job.id, self.output,
                                       self._writer_error)
        try:
            with self.link.acknowledgements() as acks:
                follower = asyncio.create_task(self._follow(acks), name="runner-acks")
                try:
                    await self._stream_all()
                    await self.link.drain()
                finally:
                    await cancel_and_wait(follower)
                    for ack in acks.take():  # delivered while the follower was stopping
                        self.on_ack(ack)
            if self._cancelled:
                raise JobCancelled(f"cancelled after the last layer ({self.completed + 1})")
            if self.state == JobState.PAUSED:  # paused after the last line: nothing to hold
                await self.link.resume(())
            self._check_marks()
        finally:
            self.eta.stop()
            await self.writer.close()
        self._save(self.output.flush)

    async def _stream_all(self) -> None:
        try:
            self._set_state(JobState.HEATING)
            await self._stream(self.source.preamble(), PREAMBLE, write=self.write_preamble)
            for index in range(self.first, self.layers):
                self.streaming_layer = index
                lines = await self._layer(index)
                await self._stream(lines, index, write=True,
                                   skip=self.skip if index == self.first else 0)
            await self._stream(self.source.ending(), ENDING, write=True)
        except StreamCancelled:
            self._cancelled = True
        if self._cancelled:
            raise JobCancelled(f"cancelled at layer {self.completed + 1}")

    async def _follow(self, acks: AckChannel) -> None:
        async for ack in acks:
            self.on_ack(ack)

    async def _layer(self, index: int) -> list[str]:
        """Layer ``index``'s lines; while it is not ready, the status is refreshed when
        what it waits for changes (``waiting_for``: a stress analysis still running)."""
        task = asyncio.ensure_future(self.source.layer(index))
        shown = None
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=WAIT_POLL_S)
                now = None if task.done() else self.waiting()
                if now != shown:
                    shown = now
                    self._publish()
        except asyncio.CancelledError:
            task.cancel()
            raise
        return task.result()

    async def _stream(self, lines: list[str], layer: int, write: bool, skip: int = 0) -> None:
        if write and lines:
            self._save(self.output.write, "\n".join(lines) + "\n")
            # to the kernel (no fsync: that is the checkpoint writer's): readers of the
            # file at this layer's event (the job tracker) find the whole layer there
            self._save(self.output.flush)
        done: list[str] = []
        batch: list[tuple[str, Hashable | None]] = []
        index = 0
        seq = self._seq
        for line in lines:
            command = strip_comment(line)
            if not command:
                continue
            if len(done) < skip:
                done.append(command)  # carried out before the interruption
                if len(done) == skip:
                    # not lines of the job: untagged, ahead of the layer's rest
                    batch.extend((move, None) for move in reentry_moves(done))
                index += 1
                continue
            batch.append((command, JobLine(seq, layer, index)))
            seq += 1
            index += 1
        if self._cancelled:
            raise StreamCancelled("job cancelled")
        # the layer's lines handed over in one call (the link writes them as the window
        # has room): the loop waits once a layer, not once a line
        await self.link.send_many(batch)
        self._seq = seq
        offset = self._save(self.output.tell)
        self._marks.append(_Mark(self._seq - 1, layer, offset if offset is not None else -1))
        self._check_marks()

    def on_ack(self, ack: Ack) -> None:
        """The printer acknowledged a line: a job line (tagged :class:`JobLine`) moves the
        marks on and hands the newest checkpoint to the writer; never waits on a disk or
        the store. Untagged lines (re-entry, park moves) are not the job's.
        """
        tag = ack.tag
        if not isinstance(tag, JobLine):
            return
        if not self._extruded and tag.layer >= 0 and _extrudes(ack.command):
            self._extruded = True
            log.info("job %s %s: first extruding move acknowledged (layer %d)", self.job.id,
                     self.job.name, tag.layer)
            self.source.started()
        self.lines_acked += 1
        self._last_seq = tag.seq
        self._check_marks()
        if tag.layer > self.completed or tag.layer == ENDING:  # the ending follows the last
            self._layer_lines = tag.index + 1
        elif tag.layer == PREAMBLE:
            self._layer_lines = self.skip  # the skipped commands were carried out before
        else:
            self._layer_lines = 0
        if self._print_started is not None and self.writer is not None:
            self.writer.submit(Checkpoint(self.completed, self.lines_acked, self._offset,
                                          self._layer_lines))
        now = time.monotonic()
        if now - self._last_publish > 0.25:
            self._publish()

    def _check_marks(self) -> None:
        marks = self._marks
        while marks and marks[0].seq <= self._last_seq:
            mark = marks.popleft()
            if mark.layer == PREAMBLE:
                self._print_started = time.monotonic()
                self.eta.start(self._print_started, measure_now=False)
                if mark.offset > 0:
                    self._offset = mark.offset  # a resume in layer 0 keeps the start block
                if self.state == JobState.HEATING:
                    self._set_state_off_loop(JobState.PRINTING)
            elif mark.layer >= 0:
                self._layer_complete(mark)

    def _layer_complete(self, mark: _Mark) -> None:
        self.completed = mark.layer
        if mark.offset >= 0:
            self._offset = mark.offset
        self._layers_timed += 1
        self._last_layer_at = time.monotonic()
        self.eta.layer_done(mark.layer, self._last_layer_at)
        status = self._publish()
        eta = duration(status.eta_s)
        log.info(
            "job %s %s: layer %d/%d, %.1f %%, ETA %s",
            self.job.id, self.job.name, mark.layer + 1, self.layers, status.progress * 100, eta,
        )
        self.life.publish(LayerDone(self.job.id, self.job.name, mark.layer, self.layers))

    def _writer_error(self, what: str, message: str) -> None:
        """The checkpoint writer could not write the G-code file, or the store."""
        if what == "file":
            self._file_failed(message)
            return
        log.error("job %s: %s", self.job.id, message)
        self.life.publish(JobError(self.job.id, message))

    def _file_failed(self, message: str) -> None:
        if self.output_error is not None:
            return
        self.output_error = message
        if self.writer is not None:
            self.writer.file_failed()
        log.error("job %s %s: %s; printing goes on", self.job.id, self.job.name, message)
        self.life.publish(JobError(self.job.id, message))

    def _save(self, action: Callable[..., Any], *args: Any) -> Any:
        """Run one operation on the G-code file; a failure (disk full) stops the file only.

        The print goes on; the job can no longer be resumed from a checkpoint and
        its G-code file is not kept. Returns the operation's result, or None.
        """
        if self.output_error is not None:
            return None
        try:
            return action(*args)
        except OSError as exc:
            self._file_failed(f"the G-code file could not be written: {exc.strerror or exc}")
            return None

    # -- status ---------------------------------------------------------------

    def status(self) -> JobStatus:
        """The job part of the status snapshot."""
        done = self.completed + 1
        progress = done / self.layers if self.layers else 0.0
        eta = self.eta.remaining(time.monotonic())
        eta = None if eta is None else round(eta, 1)
        filament = self.eta.filament()
        used, total = (None, None) if filament is None else (
            round(filament[0], 1), round(filament[1], 1))
        return JobStatus(
            id=self.job.id,
            name=self.job.name,
            layer=layer_in_progress(self.completed, self.layers),
            layers=self.layers,
            progress=round(min(progress, 1.0), 4),
            lines_acked=self.lines_acked,
            elapsed_s=round(time.monotonic() - self._started, 1),
            eta_s=eta,
            layers_ready_ahead=self.source.ready_ahead,
            waiting_for=self.waiting(),
            filament_used_mm=used,
            filament_total_mm=total,
        )

    def _publish(self) -> JobStatus:
        self._last_publish = time.monotonic()
        status = self.status()
        self.life.show_job(status)
        return status

    def _set_state_off_loop(self, state: JobState) -> None:
        """:meth:`_set_state` for the acknowledgement follower: the store is written in
        the checkpoint writer's thread (nothing in the loop that reads the printer waits
        for SQLite), the snapshot once it is recorded."""
        if self.writer is None:
            self._set_state(state)
            return
        self.state = state
        job_id, layers = self.job.id, self.layers
        self.writer.submit_state(
            lambda store: self.life.record(job_id, state, store=store, layers=layers),
            lambda: self.life.show(state, self.status()),
        )

    async def _states_written(self) -> None:
        """Wait until the state changes handed to the checkpoint writer are recorded
        (a pause or resume then follows them, in the store as in the snapshot)."""
        if self.writer is not None:
            await self.writer.states_written()

    def _set_state(self, state: JobState) -> None:
        """Move to ``state`` (recorded and shown by the job's life), or only show the
        progress when the job is in it already: the runner's ``state`` is the move last
        handed to its life, never read back from the store."""
        if state != self.state:
            self.life.enter(self.job.id, state, status=self.status(), layers=self.layers)
        else:
            self.life.show_job(self.status())
        self.state = state


def _extrudes(command: str) -> bool:
    """True for a move in X or Y that lays filament (``G1``-``G3`` with a positive ``E``)."""
    words = command.split()
    if not words or words[0] not in ("G1", "G2", "G3"):
        return False
    axes = {word[0] for word in words[1:]}
    if not axes & {"X", "Y"}:
        return False
    for word in words[1:]:
        if word[0] == "E":
            try:
                return float(word[1:]) > 0
            except ValueError:
                return False
    return False


def open_output(path: Path, keep_bytes: int) -> IO[str]:
    """The job's G-code file being written: fresh, or cut back to a checkpoint's length."""
    if keep_bytes <= 0:
        return open(path, "w", encoding="utf-8", newline="\n")
    if not path.exists():
        raise OSError(f"{path.name} is missing: the job cannot resume at its checkpoint")
    if path.stat().st_size < keep_bytes:
        raise OSError(f"{path.name} is shorter than its checkpoint ({keep_bytes} bytes)")
    handle = open(path, "r+", encoding="utf-8", newline="\n")  # noqa: SIM115
    handle.truncate(keep_bytes)
    handle.seek(keep_bytes)
    return handle
