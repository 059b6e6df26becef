"""The fleet table's data: every printer's newest status, its order, filter and counts."""

from __future__ import annotations

from dataclasses import dataclass

from hostd.api import Snapshot, bar, duration

# Problems first: a lower rank sorts higher in the table.
RANKS = {"error": 0, "offline": 1, "paused": 2, "heating": 3, "printing": 3, "idle": 4}
COUNTED = ("error", "offline", "paused", "heating", "printing", "idle")
COLUMNS = (  # key, heading, width
    ("printer", "printer", 14),
    ("state", "state", 8),
    ("job", "job", 16),
    ("progress", "progress", 13),
    ("layer", "layer", 7),
    ("eta", "ETA", 7),
    ("hotend", "hotend", 7),
    ("bed", "bed", 5),
)
BAR_WIDTH = 8


@dataclass
class PrinterEntry:
    """What is known of one printer: its last status and whether its connection is up."""

    snapshot: Snapshot | None = None
    online: bool | None = None

    @property
    def state(self) -> str:
        """``offline`` once its last will said so; else the state of its last status."""
        if self.online is False:
            return "offline"
        if self.snapshot is None:
            return "idle"
        return self.snapshot.state


def progress_bar(fraction: float) -> str:
    """A ``BAR_WIDTH``-cell bar in eighths plus a percentage, e.g. ``█████▌     55%``."""
    fraction = min(max(fraction, 0.0), 1.0)
    return f"{bar(fraction, BAR_WIDTH, empty=' ')} {fraction * 100:3.0f}%"


def _temp(actual: float, target: float) -> str:
    return f"{actual:.0f}/{target:.0f}" if target else f"{actual:.0f}"


def row_cells(printer: str, entry: PrinterEntry) -> tuple[str, ...]:
    """The plain text of each column (``COLUMNS`` order) for one printer."""
    snap = entry.snapshot
    state = entry.state
    if snap is None:
        return (printer, state, "", "", "", "", "", "")
    job = snap.job
    name = job.name if job else (snap.error or "")
    if job is None:
        progress = layer = eta = ""
    else:
        progress = progress_bar(job.progress)
        layer = f"{job.layer + 1}/{job.layers}" if job.layers else ""  # from 1, as everywhere
        eta = duration(job.eta_s)
    if state == "error" and snap.error:
        name = snap.error
    hot, bed = snap.temps.hotend, snap.temps.bed
    return (printer, state, name, progress, layer, eta, _temp(hot.actual, hot.target),
            _temp(bed.actual, bed.target))


def matches(printer: str, entry: PrinterEntry, query: str) -> bool:
    """True when every word of ``query`` is in the printer's name or job, or starts its state."""
    state = entry.state
    job = entry.snapshot.job.name.lower() if entry.snapshot and entry.snapshot.job else ""
    name = printer.lower()
    return all(
        word in name or word in job or state.startswith(word) for word in query.lower().split()
    )


class FleetModel:
    """Printers by id, with the ids changed since the table last took them."""

    def __init__(self) -> None:
        self.entries: dict[str, PrinterEntry] = {}
        self._dirty: set[str] = set()

    def _entry(self, printer: str) -> PrinterEntry:
        entry = self.entries.get(printer)
        if entry is None:
            entry = self.entries[printer] = PrinterEntry()
        return entry

    def put_status(self, printer: str, snapshot: Snapshot) -> None:
        """A new status of ``printer`` (an ``offline`` will stands until ``online`` again)."""
        self._entry(printer).snapshot = snapshot
        self._dirty.add(printer)

    def put_online(self, printer: str, online: bool) -> None:
        """The printer's ``online`` topic changed (False: its last will or a clean stop)."""
        self._entry(printer).online = online
        self._dirty.add(printer)

    def take_dirty(self) -> set[str]:
        """The printers changed since the last call."""
        dirty, self._dirty = self._dirty, set()
        return dirty

    def rank(self, printer: str) -> int:
        """Sort rank of the printer's state (unknown states count as errors)."""
        return RANKS.get(self.entries[printer].state, 0)

    def sort_key(self, printer: str) -> tuple[int, str]:
        """Problems first, then by name."""
        return (self.rank(printer), printer)

    def counts(self) -> dict[str, int]:
        """Printers per state, in ``COUNTED`` order (other states under ``error``)."""
        found = dict.fromkeys(COUNTED, 0)
        for entry in self.entries.values():
            state = entry.state
            found[state if state in found else "error"] += 1
        return found

    def ordered(self, query: str = "") -> list[str]:
        """The ids shown under ``query``, in table order."""
        shown = [p for p, e in self.entries.items() if not query or matches(p, e, query)]
        return sorted(shown, key=self.sort_key)
