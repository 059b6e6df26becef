"""Print history: one record per finished job and the totals, in their own SQLite file."""

from __future__ import annotations

import contextlib
import json
import logging
import sqlite3
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

log = logging.getLogger("hostd.publishing.history")

HISTORY_FILE = "history.sqlite3"
OUTCOMES = ("done", "failed", "cancelled")
PRINTING_STATES = ("heating", "printing")  # time counted as print time (pauses are not)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS prints (
    job_id TEXT NOT NULL,
    name TEXT NOT NULL,
    record TEXT NOT NULL,
    ended REAL NOT NULL
)
"""


@dataclass(frozen=True)
class PrintRecord:
    """One finished job. Times are Unix seconds; ``print_s`` leaves pauses out.

    ``retunes``: [first layer, {flat key: value}]; ``cancelled``: [body, first
    layer without it]; ``model``: where the model file went (done/ or failed/).
    """

    job_id: str
    name: str
    outcome: str
    ended: float
    reason: str | None = None
    kind: str = "stl"
    started: float | None = None
    print_s: float = 0.0
    total_s: float = 0.0
    layers: int = 0
    layers_done: int = 0
    filament_mm: float = 0.0
    filament_g: float = 0.0
    infill_field: str = ""
    settings: dict[str, Any] = field(default_factory=dict)
    retunes: list[list[Any]] = field(default_factory=list)
    cancelled: list[list[int]] = field(default_factory=list)
    model: str = ""
    sha256: str = ""

    def brief(self) -> dict[str, Any]:
        """The few fields the status snapshot and the MQTT summary carry."""
        return {"id": self.job_id, "name": self.name, "outcome": self.outcome,
                "ended": round(self.ended, 1), "print_s": round(self.print_s, 1),
                "filament_g": round(self.filament_g, 2)}


class History:
    """The history file: records added one transaction each, read newest first."""

    def __init__(self, path: Path, readonly: bool = False) -> None:
        if readonly:
            if not path.exists():
                raise FileNotFoundError(f"no print history at {path}")
            self._db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=10.0)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(str(path), isolation_level=None, timeout=10.0)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute(_SCHEMA)

    def close(self) -> None:
        self._db.close()

    def add(self, record: PrintRecord) -> None:
        """Append one record (committed before it returns)."""
        self._db.execute("INSERT INTO prints VALUES (?, ?, ?, ?)",
                         (record.job_id, record.name, json.dumps(asdict(record)), record.ended))

    def records(self, limit: int | None = None) -> list[PrintRecord]:
        """Records, newest first; at most ``limit`` of them."""
        query = "SELECT record FROM prints ORDER BY ended DESC, rowid DESC"
        rows = self._db.execute(query + (" LIMIT ?" if limit else ""),
                                (limit,) if limit else ()).fetchall()
        return [PrintRecord(**json.loads(row[0])) for row in rows]

    def find(self, ref: str) -> PrintRecord:
        """The record of job ``ref`` (an id), or else the newest one named ``ref``."""
        for column in ("job_id", "name"):
            row = self._db.execute(
                f"SELECT record FROM prints WHERE {column} = ? ORDER BY rowid DESC LIMIT 1",
                (ref,),
            ).fetchone()
            if row is not None:
                return PrintRecord(**json.loads(row[0]))
        raise KeyError(f"no job {ref!r} in the print history")

    def totals(self) -> dict[str, Any]:
        """Jobs by outcome, total and longest print time (s), filament (mm, g), success rate."""
        records = self.records()
        done = [r for r in records if r.outcome == "done"]
        return {
            "jobs": len(records),
            "done": len(done),
            "failed": sum(r.outcome == "failed" for r in records),
            "cancelled": sum(r.outcome == "cancelled" for r in records),
            "total_print_s": round(sum(r.print_s for r in records), 2),
            "total_filament_mm": round(sum(r.filament_mm for r in records), 2),
            "total_filament_g": round(sum(r.filament_g for r in records), 2),
            "longest_print_s": round(max((r.print_s for r in done), default=0.0), 2),
            "success_rate": round(len(done) / len(records), 4) if records else None,
        }

    def summary(self, last: int = 5) -> dict[str, Any]:
        """Totals and the last ``last`` jobs in brief (the retained MQTT history topic)."""
        return {"totals": self.totals(), "last": [r.brief() for r in self.records(last)]}


class Store(Protocol):
    """The parts of ``hostd.jobs.jobstore.JobStore`` a record is built from."""

    def get(self, job_id: str) -> Any: ...
    def history(self, job_id: str) -> list[Any]: ...
    def settings_changes(self, job_id: str) -> list[tuple[int, dict[str, Any]]]: ...
    def cancelled_objects(self, job_id: str) -> list[tuple[int, int]]: ...


class HistoryRecorder:
    """A hub listener: at each ``done``, ``failed`` or ``cancelled`` event, one record.

    Built from the job store (settings, times, retunes, cancelled bodies), the
    done G-code's header (filament, as the file says) or else the job
    tracker's count of the layers printed. ``on_record`` is called with the
    new record (the daemon puts the last jobs into the status snapshot).
    """

    def __init__(self, history: History, store: Store, tracker: Any = None,
                 on_record: Any = None) -> None:
        self.history = history
        self.store = store
        self.tracker = tracker
        self.on_record = on_record

    def on_event(self, event: dict[str, Any]) -> None:
        if event.get("event") not in OUTCOMES or event.get("id") is None:
            return
        try:
            record = self.build(event)
            self.history.add(record)
        except (sqlite3.Error, OSError, LookupError) as exc:  # the print is over; log, go on
            log.error("job %s: not recorded in the print history: %s", event.get("id"), exc)
            return
        if self.on_record is not None:
            self.on_record(record)

    def build(self, event: dict[str, Any]) -> PrintRecord:
        """The record of the job the outcome ``event`` ends."""
        job = self.store.get(str(event["id"]))
        ended = job.finished or float(event.get("ts", 0.0))
        print_s = _time_in(self.store.history(job.id), PRINTING_STATES, ended)
        filament_mm = filament_g = 0.0
        gcode = event.get("gcode")
        figures = _header_filament(Path(gcode)) if gcode else None
        info = self.tracker.info() if self.tracker is not None else None
        if figures is not None:
            filament_mm, filament_g = figures
        elif info is not None and str(info["id"]) == job.id:
            filament_mm, filament_g = info["filament_mm"], info["filament_g"]
        suffix = Path(job.name).suffix.lower()
        return PrintRecord(
            job_id=job.id, name=job.name, outcome=str(event["event"]), ended=ended,
            reason=event.get("reason"), kind=job.kind, started=job.started,
            print_s=round(print_s, 2), total_s=round(ended - job.started, 2) if job.started else 0,
            layers=job.layers, layers_done=job.layer + 1,
            filament_mm=round(filament_mm, 2), filament_g=round(filament_g, 2),
            infill_field=str(job.settings.get("infill.field", "")) if job.kind != "gcode" else "",
            settings=dict(job.settings),
            retunes=[[first, changes] for first, changes in self.store.settings_changes(job.id)],
            cancelled=[[body, first] for body, first in self.store.cancelled_objects(job.id)],
            model=f"{job.outcome}{suffix}" if job.outcome else job.path, sha256=job.sha256,
        )


def _time_in(entries: list[Any], states: tuple[str, ...], end: float) -> float:
    """Seconds spent in ``states`` according to a job's state changes (oldest first)."""
    total = 0.0
    for entry, following in zip(entries, [*entries[1:], None], strict=True):
        if entry.to_state in states:
            total += max(0.0, (following.ts if following is not None else end) - entry.ts)
    return total


def _header_filament(path: Path) -> tuple[float, float] | None:
    """``; filament used [mm]`` and ``[g]`` from the first lines of a G-code file, or None."""
    found: dict[str, float] = {}
    with contextlib.suppress(OSError, ValueError), open(path, encoding="utf-8") as handle:
        for _number, line in zip(range(60), handle, strict=False):
            for unit in ("mm", "g"):
                if line.startswith(f"; filament used [{unit}] ="):
                    found[unit] = float(line.split("=", 1)[1])
    if "mm" not in found:
        return None
    return found["mm"], found.get("g", 0.0)
