"""The job store: jobs, their state machine, checkpoints and history in SQLite (WAL)."""

from __future__ import annotations

import contextlib
import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hostd.jobs.jobstate import ACTIVE_STATES, FINAL_STATES, STATES, TRANSITIONS, JobState

# the state machine lives in hostd.jobs.jobstate; these names stay importable from here
__all__ = [
    "ACTIVE_STATES", "FINAL_STATES", "STATES", "TRANSITIONS", "HistoryEntry", "Job",
    "JobNotFound", "JobState", "JobStore", "JobStoreError", "TransitionError",
]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    source TEXT NOT NULL,
    path TEXT NOT NULL,
    kind TEXT NOT NULL,
    sha256 TEXT NOT NULL,
    size INTEGER NOT NULL DEFAULT -1,
    settings TEXT NOT NULL,
    state TEXT NOT NULL,
    position REAL NOT NULL,
    layers INTEGER NOT NULL DEFAULT 0,
    layer INTEGER NOT NULL DEFAULT -1,
    lines_acked INTEGER NOT NULL DEFAULT 0,
    gcode_bytes INTEGER NOT NULL DEFAULT 0,
    layer_lines INTEGER NOT NULL DEFAULT 0,
    resume_from INTEGER,

    error TEXT,
    outcome TEXT,
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    updated REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS history (
    seq INTEGER NOT NULL REFERENCES jobs(seq),
    ts REAL NOT NULL,
    from_state TEXT,
    to_state TEXT NOT NULL,
    layer INTEGER NOT NULL,
    note TEXT NOT NULL DEFAULT ''
);
CREATE TABLE IF NOT EXISTS settings_changes (
    seq INTEGER NOT NULL REFERENCES jobs(seq),
    ts REAL NOT NULL,
    from_layer INTEGER NOT NULL,
    changes TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS cancelled_objects (
    seq INTEGER NOT NULL REFERENCES jobs(seq),
    ts REAL NOT NULL,
    body INTEGER NOT NULL,
    from_layer INTEGER NOT NULL
);
"""


class JobStoreError(RuntimeError):
    """A job store operation was refused."""


class JobNotFound(JobStoreError):
    """No job has that id (or name)."""


class TransitionError(JobStoreError):
    """The job's state machine does not allow that move."""


@dataclass(frozen=True)
class Job:
    """One job as recorded. ``layer`` is the last completed layer (-1 = none yet)."""

    id: str
    name: str
    source: str
    path: str
    kind: str
    sha256: str
    settings: dict[str, Any]
    state: JobState
    position: float
    layers: int
    layer: int
    lines_acked: int
    gcode_bytes: int
    resume_from: int | None
    error: str | None
    outcome: str | None
    created: float
    started: float | None
    finished: float | None
    layer_lines: int = 0  # commands of layer ``layer + 1`` acknowledged
    size: int = -1  # bytes of the model whose ``sha256`` was taken (-1: not known)


@dataclass(frozen=True)
class HistoryEntry:
    """One state change of a job."""

    ts: float
    from_state: str | None
    to_state: str
    layer: int
    note: str


class JobStore:
    """SQLite-backed record of every job; each change is one short transaction.

    One connection, usable from any thread (the checkpoint writer records from
    its own): a lock keeps each transaction and each read whole.
    """

    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._lock = threading.RLock()
        self._db = sqlite3.connect(
            str(path), isolation_level=None, timeout=10.0, check_same_thread=False
        )
        self._db.row_factory = sqlite3.Row
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("PRAGMA foreign_keys=ON")
        with self._tx():
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    self._db.execute(statement)
            columns = {row[1] for row in self._db.execute("PRAGMA table_info(jobs)")}
            if "layer_lines" not in columns:  # a store made before the column
                self._db.execute(
                    "ALTER TABLE jobs ADD COLUMN layer_lines INTEGER NOT NULL DEFAULT 0"
                )
            if "size" not in columns:  # a store made before the column: sizes unknown
                self._db.execute("ALTER TABLE jobs ADD COLUMN size INTEGER NOT NULL DEFAULT -1")

    def close(self) -> None:
        """Close the database (every change is already committed)."""
        with self._lock:
            self._db.close()

    @contextlib.contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._commit()

    def _commit(self) -> None:
        """End the transaction under way (one fsync of the write-ahead log)."""
        self._db.execute("COMMIT")

    def _read(self, sql: str, params: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        with self._lock:
            return self._db.execute(sql, params).fetchall()

    # -- reading --------------------------------------------------------------

    def get(self, job_id: str) -> Job:
        """The job with this id; raises JobNotFound."""
        row = None
        if str(job_id).isdigit():
            rows = self._read("SELECT * FROM jobs WHERE seq = ?", (int(job_id),))
            row = rows[0] if rows else None
        if row is None:
            raise JobNotFound(f"no job {job_id!r}")
        return _job(row)

    def find(self, ref: str) -> Job:
        """A job by id, or else the newest job with that name."""
        with contextlib.suppress(JobNotFound):
            return self.get(ref)
        rows = self._read("SELECT * FROM jobs WHERE name = ? ORDER BY seq DESC LIMIT 1", (ref,))
        if not rows:
            raise JobNotFound(f"no job {ref!r}")
        return _job(rows[0])

    def jobs(self, *states: str) -> list[Job]:
        """Jobs in the given states (all when none given), queued ones in queue order."""
        if states:
            marks = ",".join("?" * len(states))
            rows = self._read(
                f"SELECT * FROM jobs WHERE state IN ({marks}) ORDER BY position, seq", states
            )
        else:
            rows = self._read("SELECT * FROM jobs ORDER BY seq")
        return [_job(row) for row in rows]

    def queued(self) -> list[Job]:
        """The queue, first job first."""
        return self.jobs("queued")

    def interrupted(self) -> list[Job]:
        """Jobs a crash or power cut stopped, oldest first."""
        return sorted(self.jobs("interrupted"), key=lambda job: int(job.id))

    def history(self, job_id: str) -> list[HistoryEntry]:
        """Every state change of the job, oldest first."""
        rows = self._read(
            "SELECT ts, from_state, to_state, layer, note FROM history WHERE seq = ? "
            "ORDER BY rowid",
            (int(self.get(job_id).id),),
        )
        return [HistoryEntry(*row) for row in rows]

    def settings_changes(self, job_id: str) -> list[tuple[int, dict[str, Any]]]:
        """Retunes of the job: (first layer they apply to, changed flat keys), in order."""
        rows = self._read(
            "SELECT from_layer, changes FROM settings_changes WHERE seq = ? ORDER BY rowid",
            (int(job_id),),
        )
        return [(row[0], json.loads(row[1])) for row in rows]

    def cancelled_objects(self, job_id: str) -> list[tuple[int, int]]:
        """Bodies left out of the job: (body index, first layer without it), in order."""
        rows = self._read(
            "SELECT body, from_layer FROM cancelled_objects WHERE seq = ? ORDER BY rowid",
            (int(job_id),),
        )
        return [(row[0], row[1]) for row in rows]

    # -- writing --------------------------------------------------------------

    def add(
        self,
        name: str,
        source: str,
        path: str,
        kind: str,
        sha256: str,
        settings: dict[str, Any],
        size: int = -1,
    ) -> Job:
        """Record a new queued job at the end of the queue and return it (``size``: the
        bytes of the model ``sha256`` is the hash of)."""
        now = time.time()
        with self._tx() as db:
            (last,) = db.execute("SELECT COALESCE(MAX(position), 0) FROM jobs").fetchone()
            cur = db.execute(
                "INSERT INTO jobs (name, source, path, kind, sha256, size, settings, state, "
                "position, created, updated) VALUES (?, ?, ?, ?, ?, ?, ?, 'queued', ?, ?, ?)",
                (name, source, path, kind, sha256, size, json.dumps(settings), last + 1, now,
                 now),
            )
            seq = cur.lastrowid
            db.execute(
                "INSERT INTO history VALUES (?, ?, NULL, 'queued', -1, 'taken')", (seq, now)
            )
        return self.get(str(seq))

    def set_path(self, job_id: str, path: str) -> Job:
        """Record where the job's model now lives (its folder in the state area)."""
        with self._tx() as db:
            db.execute("UPDATE jobs SET path = ? WHERE seq = ?", (path, int(job_id)))
        return self.get(job_id)

    def set_digest(self, job_id: str, sha256: str, size: int = -1) -> Job:
        """Record the SHA-256 and size of the job's model (taken again after it changed)."""
        with self._tx() as db:
            db.execute("UPDATE jobs SET sha256 = ?, size = ?, updated = ? WHERE seq = ?",
                       (sha256, size, time.time(), int(job_id)))
        return self.get(job_id)

    def transition(self, job_id: str, to_state: str, note: str = "", **fields: Any) -> Job:
        """Move a job to ``to_state`` if allowed, with optional column updates, atomically.

        ``fields`` may set ``layers``, ``error``, ``outcome``, ``resume_from``,
        ``layer``, ``lines_acked``, ``gcode_bytes``, ``layer_lines``.
        Raises TransitionError when the state machine forbids the move.
        """
        allowed = {"layers", "error", "outcome", "resume_from", "layer", "lines_acked",
                   "gcode_bytes", "layer_lines"}
        unknown = set(fields) - allowed
        if unknown:
            raise ValueError(f"cannot set {sorted(unknown)}")
        now = time.time()
        with self._tx() as db:
            row = db.execute(
                "SELECT state, layer, started FROM jobs WHERE seq = ?", (int(job_id),)
            ).fetchone()
            if row is None:
                raise JobNotFound(f"no job {job_id!r}")
            state = row["state"]
            if to_state not in TRANSITIONS[state]:
                raise TransitionError(f"job {job_id} is {state}; it cannot become {to_state}")
            sets = dict(fields, state=to_state, updated=now)
            if to_state in ("slicing", "printing") and row["started"] is None:
                sets["started"] = now
            if to_state in FINAL_STATES:
                sets["finished"] = now
            if to_state == "queued":
                (first,) = db.execute(
                    "SELECT COALESCE(MIN(position), 1) FROM jobs WHERE state = 'queued'"
                ).fetchone()
                sets["position"] = first - 1
            assignments = ", ".join(f"{key} = ?" for key in sets)
            db.execute(
                f"UPDATE jobs SET {assignments} WHERE seq = ?", (*sets.values(), int(job_id))
            )
            db.execute(
                "INSERT INTO history VALUES (?, ?, ?, ?, ?, ?)",
                (int(job_id), now, state, to_state, fields.get("layer", row["layer"]), note),
            )
        return self.get(job_id)

    def checkpoint(
        self, job_id: str, layer: int, lines_acked: int, gcode_bytes: int, layer_lines: int = 0
    ) -> None:
        """Record that ``layer`` is complete and ``layer_lines`` commands of the next one.

        ``lines_acked`` counts every job line acknowledged; ``gcode_bytes`` is
        the length of the job's G-code file through ``layer``.
        """
        with self._tx() as db:
            db.execute(
                "UPDATE jobs SET layer = ?, lines_acked = ?, gcode_bytes = ?, layer_lines = ?, "
                "updated = ? WHERE seq = ?",
                (layer, lines_acked, gcode_bytes, layer_lines, time.time(), int(job_id)),
            )

    def reopen(self, durable: bool = True) -> JobStore:
        """Another connection to the same database (for use from another thread).

        Not ``durable``: its commits do not wait for the disk (``synchronous=NORMAL``);
        they survive the process being killed, and a power cut may undo the last ones.
        """
        store = type(self)(self.path)
        if not durable:
            store.relax()
        return store

    def relax(self) -> None:
        """Commits on this connection no longer wait for the disk (WAL, ``synchronous=NORMAL``)."""
        with self._lock:
            self._db.execute("PRAGMA synchronous=NORMAL")

    def record_settings(self, job_id: str, from_layer: int, changes: dict[str, Any]) -> None:
        """Record a retune: ``changes`` (flat keys) apply from ``from_layer`` on."""
        with self._tx() as db:
            db.execute(
                "INSERT INTO settings_changes VALUES (?, ?, ?, ?)",
                (int(job_id), time.time(), from_layer, json.dumps(changes)),
            )

    def record_cancelled_object(self, job_id: str, body: int, from_layer: int) -> None:
        """Record that ``body`` is left out from ``from_layer`` on."""
        with self._tx() as db:
            db.execute(
                "INSERT INTO cancelled_objects VALUES (?, ?, ?, ?)",
                (int(job_id), time.time(), body, from_layer),
            )

    def forget_cancelled_object(self, job_id: str, body: int) -> None:
        """Undo :meth:`record_cancelled_object` for ``body`` (it prints again)."""
        with self._tx() as db:
            db.execute("DELETE FROM cancelled_objects WHERE seq = ? AND body = ?",
                       (int(job_id), body))

    def move(self, job_id: str, index: int) -> list[Job]:
        """Put a queued job at ``index`` (0 = next) of the queue; returns the new queue."""
        with self._tx() as db:
            rows = db.execute(
                "SELECT seq FROM jobs WHERE state = 'queued' ORDER BY position, seq"
            ).fetchall()
            order = [row[0] for row in rows]
            if not str(job_id).isdigit() or int(job_id) not in order:
                raise JobNotFound(f"job {job_id!r} is not queued")
            order.remove(int(job_id))
            order.insert(max(0, min(index, len(order))), int(job_id))
            for position, seq in enumerate(order, start=1):
                db.execute("UPDATE jobs SET position = ? WHERE seq = ?", (position, seq))
        return self.queued()


def _job(row: sqlite3.Row) -> Job:
    return Job(
        id=str(row["seq"]),
        name=row["name"],
        source=row["source"],
        path=row["path"],
        kind=row["kind"],
        sha256=row["sha256"],
        settings=json.loads(row["settings"]),
        state=JobState(row["state"]),
        position=row["position"],
        layers=row["layers"],
        layer=row["layer"],
        lines_acked=row["lines_acked"],
        gcode_bytes=row["gcode_bytes"],
        resume_from=row["resume_from"],
        layer_lines=row["layer_lines"],
        size=row["size"],
        error=row["error"],
        outcome=row["outcome"],
        created=row["created"],
        started=row["started"],
        finished=row["finished"],
    )
