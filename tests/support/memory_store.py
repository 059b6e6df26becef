"""A job store in memory, for tests with no database: the moves and checkpoints of jobs.

It keeps ``hostd.jobs.jobstore.JobStore``'s rules for what the runner and a job's life ask
of it (moves allowed by the state machine, ``started`` and ``finished`` stamped, the
checkpoint's fields); connections "reopened" from it are itself.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

from hostd.jobs.jobstate import FINAL_STATES, TRANSITIONS, JobState
from hostd.jobs.jobstore import Job, JobNotFound, TransitionError

FIELDS = {"layers", "error", "outcome", "resume_from", "layer", "lines_acked", "gcode_bytes",
          "layer_lines"}


class MemoryStore:
    """Jobs by id; :attr:`moves` lists every state change, :attr:`checkpoints` every
    checkpoint ``(layer, lines_acked, gcode_bytes, layer_lines)`` with :attr:`threads`,
    the thread that recorded it."""

    def __init__(self) -> None:
        self._jobs: dict[str, Job] = {}
        self.moves: list[tuple[str, str, str]] = []  # (job id, from, to)
        self.checkpoints: list[tuple[int, int, int, int]] = []
        self.threads: list[str] = []
        self._lock = threading.Lock()

    def add(self, name: str, settings: dict[str, Any] | None = None) -> Job:
        """A new queued job."""
        with self._lock:
            job_id = str(len(self._jobs) + 1)
            self._jobs[job_id] = Job(
                id=job_id, name=name, source=name, path=name, kind="stl", sha256="00",
                settings=settings or {}, state=JobState.QUEUED, position=len(self._jobs),
                layers=0, layer=-1, lines_acked=0, gcode_bytes=0, resume_from=None,
                error=None, outcome=None, created=time.time(), started=None, finished=None)
            self.moves.append((job_id, "", JobState.QUEUED))
            return self._jobs[job_id]

    def get(self, job_id: str) -> Job:
        """The job as recorded."""
        with self._lock:
            if job_id not in self._jobs:
                raise JobNotFound(f"no job {job_id!r}")
            return self._jobs[job_id]

    def transition(self, job_id: str, to_state: str, note: str = "", **fields: Any) -> Job:
        """Move a job to ``to_state`` if the state machine allows it, with ``fields``."""
        unknown = set(fields) - FIELDS
        if unknown:
            raise ValueError(f"cannot set {sorted(unknown)}")
        job = self.get(job_id)
        if to_state not in TRANSITIONS[job.state]:
            raise TransitionError(f"job {job_id} is {job.state}; it cannot become {to_state}")
        changes: dict[str, Any] = dict(fields, state=JobState(to_state))
        now = time.time()
        if to_state in ("slicing", "printing") and job.started is None:
            changes["started"] = now
        if to_state in FINAL_STATES:
            changes["finished"] = now
        with self._lock:
            self._jobs[job_id] = dataclasses.replace(job, **changes)
            self.moves.append((job_id, job.state, to_state))
            return self._jobs[job_id]

    def checkpoint(self, job_id: str, layer: int, lines_acked: int, gcode_bytes: int,
                   layer_lines: int = 0) -> None:
        """Record that ``layer`` is complete and ``layer_lines`` commands of the next one."""
        job = self.get(job_id)
        with self._lock:
            self._jobs[job_id] = dataclasses.replace(
                job, layer=layer, lines_acked=lines_acked, gcode_bytes=gcode_bytes,
                layer_lines=layer_lines)
            self.checkpoints.append((layer, lines_acked, gcode_bytes, layer_lines))
            self.threads.append(threading.current_thread().name)

    def states(self, job_id: str) -> list[str]:
        """The states the job went through, in order."""
        return [to for moved, _was, to in self.moves if moved == job_id]

    def reopen(self, durable: bool = True) -> MemoryStore:
        """The same store (there is no connection to open)."""
        return self

    def close(self) -> None:
        """Nothing to close."""
