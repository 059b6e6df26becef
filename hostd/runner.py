"""The just-in-time runner: streams a job layer by layer while later layers are sliced."""

from __future__ import annotations

import asyncio
import collections
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Protocol

from drivers.protocol import strip_comment
from hostd.api import JobStatus
from hostd.checkpoints import Checkpoint, CheckpointWriter
from hostd.eta import EtaModel
from hostd.joblife import JobLife
from hostd.jobstate import JobError, JobState, LayerDone, Paused, Resumed
from hostd.jobstore import Job, JobStore
from hostd.reentry import reentry_moves
from hostd.sources import LayerSource
from hostd.status import StatusHub

log = logging.getLogger("hostd.runner")

PREAMBLE = -1  # mark of the start (or resume) block, before layer 0
ENDING = -2  # mark of the end block
WAIT_POLL_S = 0.5  # while a layer is not ready, how often what it waits for is looked at


class Link(Protocol):
    """What the runner needs of the printer connection (a ``drivers.streamer.Streamer``)."""

    async def send(self, command: str) -> int: ...

    async def drain(self) -> None: ...


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
    """A point in the stream: once ``sent`` job lines are acknowledged, ``layer`` is complete.

    Counted in lines, not line numbers: the streamer renumbers (``M110``) on long jobs,
    but acknowledges every job line once, in order.
    """

    sent: int
    layer: int
    offset: int


class JobRunner:
    """Prints one job: preamble, layers ``first..n-1`` and ending, checkpointing as acknowledged.

    Lines go to the printer through ``link`` and, with their comments, to
    ``output`` (the job's G-code file being written). Acknowledgements come back
    through :meth:`on_ack`, called by the serial reader: it only counts, and hands
    the newest checkpoint (last complete layer, lines acknowledged, commands of
    the next layer acknowledged, bytes of ``output``) to a
    :class:`~hostd.checkpoints.CheckpointWriter`, which makes it durable in its
    own thread. ``skip`` commands of layer ``first`` are written to ``output``
    but not sent (a resume within that layer): in their place go the moves that
    bring the nozzle back to where they left it, not counted as job lines.
    """

    def __init__(
        self,
        job: Job,
        source: LayerSource,
        link: Link,
        store: JobStore,
        hub: StatusHub,
        output: IO[str],
        first: int,
        write_preamble: bool,
        park: Park | None = None,
        skip: int = 0,
    ) -> None:
        self.job = job
        self.source = source
        self.link = link
        self.store = store
        self.hub = hub
        self.life = JobLife(store, hub)
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
        self._sent = 0  # lines sent by this run (job lines and park moves)
        self._extra: collections.deque[int] = collections.deque()  # park moves, by count
        self.park = park or Park()
        self._acked = 0  # lines acknowledged in this run (job lines and park moves)
        self._layer_base = 0  # lines_acked when the layer in progress began, less `skip`
        self._offset = job.gcode_bytes if resumed else 0  # file length through `completed`
        self._running = asyncio.Event()
        self._running.set()
        self._cancelled = False
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

    def pause(self) -> None:
        """Stop sending after the current line; the printer empties its buffer."""
        if self.state == JobState.PAUSED:
            return
        self._running.clear()
        self._set_state(JobState.PAUSED)
        self.life.publish(Paused(self.job.id, self.job.name, self.completed))

    def resume(self) -> None:
        """Continue sending after a pause."""
        if self.state != JobState.PAUSED:
            return
        self._set_state(JobState.PRINTING if self._print_started is not None
                        else JobState.HEATING)
        self._running.set()
        self.life.publish(Resumed(self.job.id, self.job.name, self.completed))

    def cancel(self) -> None:
        """Stop the job: no further line of it is sent."""
        self._cancelled = True
        self._running.set()

    @property
    def paused(self) -> bool:
        return self.state == JobState.PAUSED

    # -- streaming ------------------------------------------------------------

    async def run(self) -> None:
        """Stream the whole job; returns when every line is acknowledged.

        Raises JobCancelled after :meth:`cancel`; CancelledError propagates (the
        daemon stopping), leaving the last checkpoint in the store.
        """
        self.writer = CheckpointWriter(self.store, self.job.id, self.output, self._writer_error)
        try:
            self._set_state(JobState.HEATING)
            await self._stream(self.source.preamble(), PREAMBLE, write=self.write_preamble)
            for index in range(self.first, self.layers):
                self.streaming_layer = index
                lines = await self._layer(index)
                await self._stream(lines, index, write=True,
                                   skip=self.skip if index == self.first else 0)
            await self._stream(self.source.ending(), ENDING, write=True)
            await self.link.drain()
            self._check_marks()
        finally:
            await self.writer.close()
        self._save(self.output.flush)

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
        for line in lines:
            command = strip_comment(line)
            if not command:
                continue
            if len(done) < skip:
                done.append(command)  # carried out before the interruption
                if len(done) == skip:
                    await self._send_extra(reentry_moves(done))
                continue
            if not self._running.is_set():
                await self._hold()
            if self._cancelled:
                raise JobCancelled(f"cancelled at layer {self.completed + 1}")
            await self.link.send(command)
            self._sent += 1
        if self._cancelled:
            raise JobCancelled(f"cancelled at layer {self.completed + 1}")
        offset = self._save(self.output.tell)
        self._marks.append(_Mark(self._sent, layer, offset if offset is not None else -1))
        self._check_marks()

    async def _hold(self) -> None:
        """While paused: lift the nozzle (once printing), wait, and put it back."""
        parked = self._print_started is not None
        if parked:
            await self._send_extra(self.park.park)
        await self._running.wait()
        if parked and not self._cancelled:
            await self._send_extra(self.park.unpark)

    async def _send_extra(self, commands: tuple[str, ...]) -> None:
        """Send moves that are not lines of the job (pause, re-entry): acknowledged apart."""
        for command in commands:
            await self.link.send(command)
            self._sent += 1
            self._extra.append(self._sent)

    def on_ack(self) -> None:
        """The printer acknowledged the oldest line of this run not yet acknowledged.

        Called by the serial reader: counts, moves the marks on and hands the
        newest checkpoint to the writer; never waits on a disk or the store.
        """
        self._acked += 1
        if self._extra and self._extra[0] == self._acked:
            self._extra.popleft()  # a park move, not a line of the job
        else:
            self.lines_acked += 1
        self._check_marks()
        if self._print_started is not None and self.writer is not None:
            self.writer.submit(Checkpoint(self.completed, self.lines_acked, self._offset,
                                          self.lines_acked - self._layer_base))
        now = time.monotonic()
        if now - self._last_publish > 0.25:
            self._publish()

    def _check_marks(self) -> None:
        marks = self._marks
        while marks and marks[0].sent <= self._acked:
            mark = marks.popleft()
            if mark.layer == PREAMBLE:
                self._print_started = time.monotonic()
                self.eta.start(self._print_started)
                if mark.offset > 0:
                    self._offset = mark.offset  # a resume in layer 0 keeps the start block
                self._layer_base = self.lines_acked - self.skip
                if self.state == JobState.HEATING:
                    # the state is recorded by the loop, not inside the reader's callback
                    asyncio.get_running_loop().call_soon(self._now_printing)
            elif mark.layer >= 0:
                self._layer_complete(mark)

    def _now_printing(self) -> None:
        if self.state == JobState.HEATING:
            self._set_state(JobState.PRINTING)

    def _layer_complete(self, mark: _Mark) -> None:
        self.completed = mark.layer
        self._layer_base = self.lines_acked
        if mark.offset >= 0:
            self._offset = mark.offset
        self._layers_timed += 1
        self._last_layer_at = time.monotonic()
        self.eta.layer_done(mark.layer, self._last_layer_at)
        status = self._publish()
        eta = "--" if status.eta_s is None else _clock(status.eta_s)
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
        return JobStatus(
            id=self.job.id,
            name=self.job.name,
            layer=max(0, min(self.completed + 1, self.layers - 1)),  # the layer in progress
            layers=self.layers,
            progress=round(min(progress, 1.0), 4),
            lines_acked=self.lines_acked,
            elapsed_s=round(time.monotonic() - self._started, 1),
            eta_s=eta,
            layers_ready_ahead=self.source.ready_ahead,
            waiting_for=self.waiting(),
        )

    def _publish(self) -> JobStatus:
        self._last_publish = time.monotonic()
        status = self.status()
        self.hub.update(job=status)
        return status

    def _set_state(self, state: JobState) -> None:
        if state != self.state or self.store.get(self.job.id).state != state:
            self.life.enter(self.job.id, state, status=self.status(), layers=self.layers)
        else:
            self.hub.update(job=self.status())
        self.state = state


def _clock(seconds: float) -> str:
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


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
