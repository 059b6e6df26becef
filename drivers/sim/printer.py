"""The simulated Marlin printer on a pseudo-terminal: the object hosts and tests use."""

from __future__ import annotations

import threading
from collections import Counter
from dataclasses import dataclass
from types import TracebackType
from typing import IO

from drivers.sim.config import FAULT_KINDS, SimulatorConfig
from drivers.sim.firmware import Firmware
from drivers.sim.wire import PtyWire

__all__ = ["FAULT_KINDS", "SimStats", "SimulatedPrinter", "SimulatorConfig"]


@dataclass(frozen=True)
class SimStats:
    """Counters of one run. Times are simulated seconds (multiply by time_scale for wall).

    ``faults`` maps a fault kind to how often it fired, ``fault_chances`` to how often it
    was drawn; ``errors`` counts line errors answered with a resend. ``motion_s`` is the
    moves' nominal time (length / feedrate); ``planned_s`` the time of the blocks the
    planner has executed, with acceleration and corners. ``underruns`` counts the times the
    planner ran empty while moves were still coming (not after a dwell, homing or heating)
    and ``starved_s`` the time it stood empty then; ``arcs`` G2/G3 moves and
    ``arc_segments`` the chords they were cut into.
    """

    lines: int
    executed: int
    errors: int
    line_number_errors: int
    checksum_errors: int
    no_checksum_errors: int
    rx_overflow_bytes: int
    rx_lost_bytes: int
    resets: int
    moves: int
    motion_s: float
    dwell_s: float
    home_s: float
    distance_mm: float
    bytes_in: int
    bytes_out: int
    faults: dict[str, int]
    fault_chances: dict[str, int]
    planned_s: float = 0.0
    underruns: int = 0
    starved_s: float = 0.0
    arcs: int = 0
    arc_segments: int = 0


class SimulatedPrinter:
    """A Marlin-like printer served on a pseudo-terminal from background threads.

    ``start()`` returns the device path a host opens; ``executed`` lists every executed
    command (without line number and checksum) in order (unless ``keep_executed`` is
    off), and ``log_path`` gets the same, one line each, flushed per line. Usable as a
    context manager.

    How it behaves, in brief (details in ``drivers.sim.firmware``):

    - Opening the port resets the printer (``reset_on_open``): after ``boot_delay_s`` it
      prints ``start``; bytes sent before that are lost. A reopen is noticed when the port
      stayed closed for about 10 ms or more.
    - Bytes cross the wire at ``baud / 10`` bytes/s, each delivered ``latency_s`` after
      its wire time (in both directions), into a receive buffer of ``rx_buffer`` bytes;
      bytes past it are lost. The firmware moves lines from it into a queue of ``bufsize``
      commands only between commands, so while it is busy the buffer fills and overflows.
    - ``ok`` is sent when a command has been executed; a move counts as executed once it
      is in the planner (``planner_blocks``), so its ``ok`` waits while the planner is full.
    - Simulated time: moves take length / feedrate, dwells and homing their time, heaters
      follow a first-order model; all multiplied by ``time_scale`` for wall time. With
      ``time_scale = 0`` the printer's clock only advances when it would wait, so
      ``M109`` still reports one temperature line per simulated second, instantly.
    - ``M155 S<s>`` auto-reports every ``s`` *wall* seconds whatever the time scale, so a
      host always sees them at the rate it asked for.
    - ``echo:busy: processing`` every keepalive interval (2 s, ``M113``) of simulated time
      while one command runs.
    """

    def __init__(self, config: SimulatorConfig | None = None) -> None:
        self.config = config or SimulatorConfig()
        self.executed: list[str] = []
        self._log: IO[str] | None = None
        self._wire = PtyWire(
            self.config.bytes_per_second,
            receive=self._on_receive,
            opened=self._on_opened,
            link_path=self.config.link_path,
            reconnect_delay_s=self.config.reconnect_delay_s,
            latency_s=self.config.latency_s,
        )
        self._firmware = Firmware(
            self.config,
            send=self._wire.send,
            wait_sent=self._wire.wait_sent,
            vanish=self._wire.vanish,
            executed=self._on_executed,
        )
        self._threads: list[threading.Thread] = []
        self._stopped = threading.Event()
        self._started = False

    # --- lifecycle ------------------------------------------------------------------

    def start(self) -> str:
        """Open the pseudo-terminal and start serving it; returns the slave device path."""
        if self._started:
            return self._wire.path
        self._started = True
        if self.config.log_path:
            self._log = open(self.config.log_path, "a", encoding="utf-8")  # noqa: SIM115
        path = self._wire.open()
        for target, name in ((self._firmware.run, "sim-firmware"), (self._report, "sim-report")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)
        return path

    def stop(self) -> None:
        """Stop every thread and close every descriptor; idempotent."""
        if self._stopped.is_set():
            return
        self._stopped.set()
        self._firmware.stop()
        self._firmware.autoreport_changed.set()
        for thread in self._threads:
            thread.join(timeout=5.0)
        self._threads.clear()
        self._wire.close()
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self) -> SimulatedPrinter:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    # --- state ----------------------------------------------------------------------

    @property
    def path(self) -> str:
        """Current device path (a new one after a disconnect fault)."""
        return self._wire.path

    @property
    def connected(self) -> bool:
        """True while a host has the port open."""
        return self._wire.connected

    @property
    def last_line(self) -> int:
        """The last accepted line number (Marlin's ``last_N``)."""
        return self._firmware.last_n

    def temperatures(self) -> str:
        """The current heater report, as M105 prints it after ``ok``."""
        return self._firmware.temperatures()

    def reset(self) -> None:
        """Press the reset button: forgets line numbers and queue, prints ``start``."""
        self._firmware.request_reset()

    def disconnect(self) -> None:
        """Pull the cable: the port vanishes once the replies already produced are out; a
        command still waiting is cut short. It comes back on a new pseudo-terminal when
        ``link_path`` is set."""
        self._firmware.request_unplug()

    def stats(self) -> SimStats:
        """A snapshot of the counters."""
        fw = self._firmware
        s, t = Counter(fw.stats), Counter(fw.times)
        return SimStats(
            lines=s["lines"],
            executed=s["executed"],
            errors=s["errors"],
            line_number_errors=s["Line Number is not Last Line Number+1"],
            checksum_errors=s["checksum mismatch"],
            no_checksum_errors=s["No Checksum with line number"],
            rx_overflow_bytes=s["rx_overflow_bytes"],
            rx_lost_bytes=s["rx_lost_bytes"],
            resets=s["resets"],
            moves=s["moves"],
            motion_s=t["motion"],
            dwell_s=t["dwell"],
            home_s=t["home"],
            distance_mm=t["distance_mm"],
            bytes_in=self._wire.bytes_in,
            bytes_out=self._wire.bytes_out,
            faults=dict(fw.faults.fired),
            fault_chances=dict(fw.faults.chances),
            planned_s=fw.planner.motion_s,
            underruns=fw.planner.underruns,
            starved_s=fw.planner.starved_s,
            arcs=s["arcs"],
            arc_segments=s["arc_segments"],
        )

    # --- callbacks from the threads ---------------------------------------------------

    def _on_receive(self, data: bytes) -> None:
        self._firmware.receive(data)

    def _on_opened(self) -> None:
        self._firmware.port_opened()

    def _on_executed(self, command: str) -> None:
        if self.config.keep_executed:
            self.executed.append(command)
        if self._log is not None:
            self._log.write(command + "\n")
            self._log.flush()

    def _report(self) -> None:
        """M155 auto-report: a temperature line every S wall seconds while enabled."""
        fw = self._firmware
        while not self._stopped.is_set():
            interval = fw.autoreport_s
            fw.autoreport_changed.clear()
            if interval <= 0.0:
                fw.autoreport_changed.wait()
                continue
            if not fw.autoreport_changed.wait(interval) and fw.autoreport_s > 0.0:
                fw.emit(fw.temperatures())
