"""The checkpoint writer: a job's progress made durable off the serial read path."""

from __future__ import annotations

import asyncio
import collections
import concurrent.futures
import logging
import os
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO

from hostd.jobs.jobstore import JobStore, JobStoreError

log = logging.getLogger("hostd.printing.checkpoints")


@dataclass(frozen=True)
class Checkpoint:
    """How far a job is, as the printer acknowledged it.

    ``layer``: last layer all of whose lines were acknowledged (-1: none);
    ``lines_acked``: job lines acknowledged in all; ``gcode_bytes``: length of
    the job's G-code file through ``layer``; ``layer_lines``: commands of
    layer ``layer + 1`` acknowledged so far.
    """

    layer: int
    lines_acked: int
    gcode_bytes: int
    layer_lines: int = 0


class CheckpointWriter:
    """Records a job's checkpoints from a thread of its own, newest first.

    :meth:`submit` never waits: it only puts the checkpoint in a queue of one
    (a newer checkpoint replaces one not yet written, which it includes). A task
    takes it, flushes the job's G-code file, and in the writer's thread fsyncs
    the file (when its length moved on) and commits the checkpoint on its own
    connection to the job store. So neither an fsync nor a commit ever runs in
    the serial reader that acknowledges the lines. The writer's commits survive
    the daemon being killed; a power cut may undo the last ones, so that a resume
    starts a little earlier, never later than the printer got.

    A state change found by the acknowledgement follower (the job printing once
    its start block is acknowledged) is recorded here too (:meth:`submit_state`),
    before the checkpoints that follow it, on a second connection that commits
    durably: a power cut never undoes it (a job it undid would be taken for one
    that printed nothing and started again over its first layer).
    """

    def __init__(
        self,
        store: JobStore,
        job_id: str,
        output: IO[str] | None,
        on_error: Callable[[str, str], None],
    ) -> None:
        """``on_error(what, message)``: ``what`` is "file" (the G-code file) or "store"."""
        self.store = store
        self.job_id = job_id
        self.output = output
        self.on_error = on_error
        self.written: Checkpoint | None = None
        self.commits = 0
        self._pending: Checkpoint | None = None
        self._ready = asyncio.Event()
        self._closing = False
        self._synced_bytes = -1
        self._thread = concurrent.futures.ThreadPoolExecutor(1, "hostd-checkpoint")
        self._connection: JobStore | None = None
        self._durable: JobStore | None = None  # for state changes
        self._states: collections.deque[
            tuple[Callable[[JobStore], object], Callable[[], None]]
        ] = collections.deque()
        self._states_written = asyncio.Event()
        self._states_written.set()
        self._file_ok = output is not None
        self._task = asyncio.get_running_loop().create_task(self._run(), name="checkpoints")

    def submit(self, checkpoint: Checkpoint) -> None:
        """Hand a checkpoint over (from the reader's callbacks); returns at once."""
        self._pending = checkpoint
        self._ready.set()

    def submit_state(self, record: Callable[[JobStore], object], then: Callable[[], None]) -> None:
        """Have ``record(store)`` (a state change) run in the writer's thread on a durable
        connection, then ``then()`` in the event loop; returns at once."""
        self._states.append((record, then))
        self._states_written.clear()
        self._ready.set()

    async def states_written(self) -> None:
        """Wait until every state change handed over is recorded (or failed)."""
        await self._states_written.wait()

    def file_failed(self) -> None:
        """The G-code file failed: checkpoints are no longer recorded (it cannot resume)."""
        self._file_ok = False
        self._pending = None

    async def close(self) -> None:
        """Write the newest checkpoint still pending, then stop the writer."""
        self._closing = True
        self._ready.set()
        try:
            await asyncio.shield(self._task)
        finally:
            self._thread.submit(self._close_connection)
            self._thread.shutdown(wait=False)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if self._pending is None and not self._states:
                if self._closing:
                    return
                await self._ready.wait()
            self._ready.clear()
            while self._states:
                record, then = self._states.popleft()
                try:
                    await loop.run_in_executor(self._thread, self._record_state, record)
                except (sqlite3.Error, JobStoreError) as exc:
                    self.on_error("store", f"state change not recorded: {exc}")
                else:
                    then()
            self._states_written.set()
            checkpoint, self._pending = self._pending, None
            if checkpoint is None:
                continue
            if not self._file_ok and self.output is not None:
                continue
            sync = checkpoint.gcode_bytes != self._synced_bytes and self.output is not None
            try:
                if sync:
                    self.output.flush()  # to the kernel: the fsync below makes it durable
                await loop.run_in_executor(self._thread, self._record, checkpoint, sync)
            except OSError as exc:
                self._file_ok = False
                self.on_error("file", f"the G-code file could not be written: "
                                      f"{exc.strerror or exc}")
                continue
            except sqlite3.Error as exc:  # printing goes on without it
                self.on_error("store", f"checkpoint not recorded: {exc}")
                continue
            if sync:
                self._synced_bytes = checkpoint.gcode_bytes
            self.written = checkpoint
            self.commits += 1

    def _record(self, checkpoint: Checkpoint, sync: bool) -> None:
        """(Writer thread) fsync the G-code file if asked, then commit the checkpoint."""
        if sync and self.output is not None:
            os.fsync(self.output.fileno())
        if self._connection is None:
            # a checkpoint a power cut undoes only makes a resume start earlier: never
            # later than the printer got, so its commits need not wait for the disk
            self._connection = self.store.reopen(durable=False)
        self._connection.checkpoint(self.job_id, checkpoint.layer, checkpoint.lines_acked,
                                    checkpoint.gcode_bytes, checkpoint.layer_lines)

    def _record_state(self, record: Callable[[JobStore], object]) -> None:
        """(Writer thread) a state change, on the durable connection."""
        if self._durable is None:
            self._durable = self.store.reopen()
        record(self._durable)

    def _close_connection(self) -> None:
        for connection in (self._connection, self._durable):
            if connection is not None:
                connection.close()
        self._connection = self._durable = None
