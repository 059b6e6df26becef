"""Hosts on the virtual clock: the protocol core, and a send-and-wait host to compare with.

Both stream a job to a :class:`~drivers.sim.virtual.VirtualPrinter` with no real time
passing, for deterministic fault tests and for the throughput benchmark's noisy rows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypedDict

from drivers.link.config import StreamerConfig, StreamStats
from drivers.link.core import LinkCore
from drivers.link.events import Acked, Connected, Event, Failed
from drivers.link.protocol import frame
from drivers.link.resend import recover
from drivers.link.responses import Response, parse_response
from drivers.sim.config import SimulatorConfig
from drivers.sim.virtual import Clock, VirtualPrinter

# commands the link adds on its own
INTERNAL = ("M110", "M115", "M503", "M155", "M105")


class _Phase(TypedDict):
    next: int  # index of the next job line to queue
    streaming: bool
    start: float
    end: float


class _SendAndWait(TypedDict):
    n: int  # the line in flight
    skip: int  # oks still to come after a Resend
    error: Response | None
    start: float
    done: bool


class NoConvergence(RuntimeError):
    """The job did not finish within the virtual time allowed."""


@dataclass
class LinkRun:
    """The outcome of one stream on the virtual clock.

    ``executed``: job commands the printer executed, in order (link's own lines removed);
    ``acked``: job commands acknowledged to the caller, in order; ``seconds``: virtual
    time from the first job line to the last acknowledgement; ``bytes_written``: every
    byte the host wrote; ``max_gap``: the longest virtual time between two writes of the
    host while streaming (a stall shows here).
    """

    executed: list[str]
    acked: list[str]
    seconds: float
    bytes_written: int
    printer: VirtualPrinter
    stats: StreamStats = field(default_factory=StreamStats)
    max_gap: float = 0.0

    @property
    def rate(self) -> float:
        """Job lines per virtual second."""
        return len(self.executed) / self.seconds if self.seconds > 0 else float("inf")


def arc_job(n: int, seed: int = 0) -> list[str]:
    """A curved perimeter of ``n`` short G1 segments (distinct lines, so order is visible)."""
    out = []
    for i in range(n):
        a = 0.01 * i + seed
        out.append(f"G1 X{100 + 40 * math.cos(a):.3f} Y{100 + 40 * math.sin(a):.3f} "
                   f"E{0.002 * (i % 97):.4f} F9000")
    return out


def job_commands(executed: list[str]) -> list[str]:
    """Executed commands without the link's own lines (a probe merged with the line after
    it by a receive overrun, ``M105*N12 M105``, whose checksum still matched, is one)."""
    return [c for c in executed if c.split(" ", 1)[0].split("*", 1)[0] not in INTERNAL]


def run_core(
    lines: list[str],
    sim: SimulatorConfig,
    link: StreamerConfig,
    *,
    printer_hook: Callable[[VirtualPrinter], None] | None = None,
    exec_s: float = 0.0,
    max_seconds: float = 1e7,
    printer_class: type[VirtualPrinter] = VirtualPrinter,
) -> LinkRun:
    """Connect the core to a fresh virtual printer (the core's own handshake, the
    streamer's), stream ``lines``, wait for every ack.

    ``printer_hook`` may set the printer's ``split`` and its lanes' ``delay`` before the
    first byte. Raises :class:`NoConvergence` past ``max_seconds`` of virtual time and
    ``RuntimeError`` if the link fails.
    """
    clock = Clock()
    core = LinkCore(link)
    acked: list[str] = []
    written = [0]
    phase: _Phase = {"next": 0, "streaming": False, "start": 0.0, "end": 0.0}
    gaps = [0.0, 0.0]  # the last write while streaming, the longest gap between two

    def handle(events: list[Event]) -> None:
        for event in events:
            if isinstance(event, Acked):
                if event.job:
                    acked.append(event.command)
            elif isinstance(event, Connected):  # the link's own handshake is done
                phase["streaming"] = True
                phase["start"] = clock.now
            elif isinstance(event, Failed):
                raise RuntimeError(f"link failed: {event.reason}")

    total = len(lines)
    queue_job, next_bytes, pending = core.queue_job, core.next_bytes, core.writer.pending

    def pump() -> None:
        if phase["streaming"]:
            queued = phase["next"]
            while len(pending) < 8 and queued < total:
                queue_job(lines[queued], queued + 3)
                queued += 1
            phase["next"] = queued
        now = clock.now
        write = printer.write
        while (data := next_bytes(now)) is not None:
            written[0] += len(data)
            write(data)
            if phase["streaming"]:
                if now - gaps[0] > gaps[1] and gaps[0] > 0.0:
                    gaps[1] = now - gaps[0]
                gaps[0] = now
        events = core.take_events()
        if events:
            handle(events)

    def on_line(text: str) -> None:
        events = core.feed(text, clock.now)
        if events:
            handle(events)
        pump()
        if phase["next"] >= total and done():
            clock.stop()  # only a line read or a tick changes what the link knows

    def done() -> bool:
        if not (phase["streaming"] and phase["next"] >= total and not pending):
            return False
        if core.settled():
            return True
        pump()  # the probe that proves every line taken
        return False

    interval = core.tick_interval()

    def tick() -> None:
        handle(core.tick(clock.now))
        pump()
        if not done():
            clock.at(clock.now + interval, tick)
        elif phase["next"] >= total:
            clock.stop()

    printer = printer_class(sim, clock, on_line, exec_s=exec_s)
    if printer_hook is not None:
        printer_hook(printer)
    core.begin_connect(0.0)
    printer.power_on()
    clock.at(interval, tick)
    outcome = clock.run(max_seconds)
    if outcome == "idle":
        raise NoConvergence("nothing left to happen and the job is not done")
    if outcome == "late":
        raise NoConvergence(f"not done after {max_seconds:g} virtual seconds")
    phase["end"] = clock.now
    return LinkRun(job_commands(printer.executed), acked, phase["end"] - phase["start"],
                   written[0], printer, core.stats, gaps[1])


def run_send_and_wait(lines: list[str], sim: SimulatorConfig, *, exec_s: float = 0.0,
                      max_seconds: float = 1e7, start_timeout_s: float = 2.0) -> LinkRun:
    """A careful one-line-at-a-time host (as OctoPrint and Printrun stream): write a line,
    wait for its ``ok``; replay the line in flight when the printer refuses it (an
    ``Error`` naming the line before it), skip the ``ok`` after a request, ignore other
    requests. Told the firmware's dialect, it takes the ``ok`` after a request for the
    line after the one in flight for that line's own where the firmware withholds it
    (``p_refuse_next``), as OctoPrint does with every such request. It waits
    ``start_timeout_s`` for a ``start`` banner that may not come, and after a reset (a
    banner mid-stream, or a refusal naming line 0) sets the numbering back with
    ``N<k> M110 N<k>`` and writes the line in flight again.
    """
    clock = Clock()
    state: _SendAndWait = {"n": 0, "skip": 0, "error": None, "start": 0.0, "done": False}
    written = [0]
    renumbering = [False]
    withheld = sim.p_refuse_next > 0

    def send(number: int) -> None:
        data = frame(number, lines[number - 1])
        written[0] += len(data)
        printer.write(data)

    def renumber() -> None:
        value = max(0, state["n"] - 1)
        data = frame(value, f"M110 N{value}")
        written[0] += len(data)
        renumbering[0] = True
        state["skip"] = 0
        printer.write(data)

    def kick() -> None:
        if state["n"] == 0 and not renumbering[0]:
            renumber()  # no banner: the board did not reset on open

    def on_line(text: str) -> None:
        response = recover(parse_response(text))
        error, state["error"] = state["error"], None
        n = state["n"]
        if response.kind == "error" and response.line is not None:
            state["error"] = response
        elif response.kind == "resend":
            if renumbering[0]:
                return
            if error is not None and error.line == 0 and n > 1 and response.line == 1:
                renumber()  # the printer lost its numbering: a reset without a banner
                return
            if error is not None and sim.ok_after_resend and (
                    error.line is None or error.line < n or not withheld):
                state["skip"] += 1
            if error is not None and error.line is not None and error.line < n:
                state["n"] = error.line + 1  # the line in flight (or one before) was refused
                send(state["n"])
        elif response.kind == "start":
            if n == 0 or not state["done"]:
                renumber()
        elif response.kind == "ok":
            if renumbering[0]:
                renumbering[0] = False
                if n == 0:
                    state["start"] = clock.now
                    state["n"] = n = 1
                send(n)
                return
            if state["skip"]:
                state["skip"] -= 1
                return
            if n >= len(lines):
                state["done"] = True
                return
            state["n"] = n + 1
            send(n + 1)

    printer = VirtualPrinter(sim, clock, on_line, exec_s=exec_s)
    printer.power_on()
    clock.at(start_timeout_s, kick)
    while not state["done"]:
        if not clock.step() or clock.now > max_seconds:
            raise NoConvergence("the send-and-wait host stalled")
    return LinkRun(job_commands(printer.executed), lines[: state["n"]],
                   clock.now - state["start"], written[0], printer)
