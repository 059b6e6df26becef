"""The just-in-time runner: streams a job layer by layer while later layers are sliced."""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Protocol

from drivers.protocol import strip_comment
from hostd.api import JobStatus
from hostd.eta import EtaModel
from hostd.jobstore import Job, JobStore
from hostd.sources import LayerSource
from hostd.status import StatusHub

log = logging.getLogger("hostd.runner")

PREAMBLE = -1  # mark of the start (or resume) block, before layer 0
ENDING = -2  # mark of the end block


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
    """Prints one job: preamble, layers ``first..n-1`` and ending, checkpointing each layer.

    Lines go to the printer through ``link`` and, with their comments, to
    ``output`` (the job's G-code file being written). Acknowledgements come back
    through :meth:`on_ack`; when every line of a layer is acknowledged the layer
    is complete and the job store records it (last layer, acknowledged lines,
    bytes of ``output``), in one transaction.
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
    ) -> None:
        self.job = job
        self.source = source
        self.link = link
        self.store = store
        self.hub = hub
        self.output = output
        self.first = first
        self.write_preamble = write_preamble
        self.layers = source.layer_count
        self.completed = first - 1
        self.lines_acked = job.lines_acked if first > 0 else 0
        self.state = "slicing"
        self._marks: collections.deque[_Mark] = collections.deque()
        self._sent = 0  # lines sent by this run (job lines and park moves)
        self._extra: collections.deque[int] = collections.deque()  # park moves, by count
        self.park = park or Park()
        self._acked = 0  # job lines acknowledged in this run
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
        self.eta = EtaModel(getattr(source, "schedule", None), self.layers, first)

    # -- commands -------------------------------------------------------------

    def pause(self) -> None:
        """Stop sending after the current line; the printer empties its buffer."""
        if self.state == "paused":
            return
        self._running.clear()
        self._set_state("paused")
        self.hub.event("paused", id=self.job.id, name=self.job.name, layer=self.completed)

    def resume(self) -> None:
        """Continue sending after a pause."""
        if self.state != "paused":
            return
        self._set_state("printing" if self._print_started is not None else "heating")
        self._running.set()
        self.hub.event("resumed", id=self.job.id, name=self.job.name, layer=self.completed)

    def cancel(self) -> None:
        """Stop the job: no further line of it is sent."""
        self._cancelled = True
        self._running.set()

    @property
    def paused(self) -> bool:
        return self.state == "paused"

    # -- streaming ------------------------------------------------------------

    async def run(self) -> None:
        """Stream the whole job; returns when every line is acknowledged.

        Raises JobCancelled after :meth:`cancel`; CancelledError propagates (the
        daemon stopping), leaving the last checkpoint in the store.
        """
        self._set_state("heating")
        await self._stream(self.source.preamble(), PREAMBLE, write=self.write_preamble)
        for index in range(self.first, self.layers):
            self.streaming_layer = index
            lines = await self.source.layer(index)
            await self._stream(lines, index, write=True)
        await self._stream(self.source.ending(), ENDING, write=True)
        await self.link.drain()
        self._check_marks()
        self._save(self.output.flush)

    async def _stream(self, lines: list[str], layer: int, write: bool) -> None:
        if write and lines:
            self._save(self.output.write, "\n".join(lines) + "\n")
        for line in lines:
            command = strip_comment(line)
            if not command:
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
        for command in commands:
            await self.link.send(command)
            self._sent += 1
            self._extra.append(self._sent)

    def on_ack(self) -> None:
        """The printer acknowledged the oldest line of this run not yet acknowledged."""
        self._acked += 1
        if self._extra and self._extra[0] == self._acked:
            self._extra.popleft()  # a park move, not a line of the job
        else:
            self.lines_acked += 1
        self._check_marks()
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
                if self.state == "heating":
                    self._set_state("printing")
            elif mark.layer >= 0:
                self._layer_complete(mark)

    def _layer_complete(self, mark: _Mark) -> None:
        self._save(self.output.flush)
        self._save(lambda: os.fsync(self.output.fileno()))
        self.completed = mark.layer
        self._layers_timed += 1
        self._last_layer_at = time.monotonic()
        self.eta.layer_done(mark.layer, self._last_layer_at)
        if self.output_error is None:
            try:
                self.store.checkpoint(self.job.id, mark.layer, self.lines_acked, mark.offset)
            except (sqlite3.Error, OSError) as exc:  # printing goes on without it
                log.error("job %s: checkpoint of layer %d not recorded: %s",
                          self.job.id, mark.layer, exc)
                self.hub.event("error", id=self.job.id, message=f"checkpoint not recorded: {exc}")
        status = self._publish()
        eta = "--" if status.eta_s is None else _clock(status.eta_s)
        log.info(
            "job %s %s: layer %d/%d, %.1f %%, ETA %s",
            self.job.id, self.job.name, mark.layer + 1, self.layers, status.progress * 100, eta,
        )
        self.hub.event("layer", id=self.job.id, name=self.job.name, layer=mark.layer,
                       layers=self.layers)

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
            self.output_error = f"the G-code file could not be written: {exc.strerror or exc}"
            log.error("job %s %s: %s; printing goes on", self.job.id, self.job.name,
                      self.output_error)
            self.hub.event("error", id=self.job.id, message=self.output_error)
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
        )

    def _publish(self) -> JobStatus:
        self._last_publish = time.monotonic()
        status = self.status()
        self.hub.update(job=status)
        return status

    def _set_state(self, state: str) -> None:
        if state != self.state or self.store.get(self.job.id).state != state:
            self.store.transition(self.job.id, state, layers=self.layers)
        self.state = state
        self.hub.update(state=state, job=self.status())


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
