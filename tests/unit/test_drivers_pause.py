"""A paused link sends nothing of the job, proved on the virtual clock: the protocol core
(``drivers.link.core``) and the virtual printer (``drivers.sim.virtual``) share one clock,
so a pause can last two virtual minutes, probes and temperature polls included, in no
wall time, and what ran when is read off that clock.

The asyncio shell's pause and resume on a pseudo-terminal (park and unpark in order, the
job resumed exactly where it stopped) is tests/integration/test_drivers_streamer.py.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from drivers.link.config import StreamerConfig
from drivers.link.core import LinkCore
from drivers.link.events import Acked, Connected, Failed
from drivers.sim.config import SimulatorConfig
from drivers.sim.virtual import Clock, VirtualPrinter

INTERNAL = ("M110", "M115", "M503", "M155", "M105")  # the link's own lines
PARK = ["G91", "G1 Z5 F600", "G90"]
UNPARK = ["G91", "G1 Z-5 F600", "G90"]
CONTROL = {*PARK, *UNPARK}  # sent by the link on a pause and a resume, not job lines
PAUSE_S = 120.0  # virtual seconds the job stays paused
EXEC_S = 0.02  # virtual seconds each command takes on the printer


def job(count: int) -> list[str]:
    """``count`` distinct moves (each one names its place in the job)."""
    return [f"G1 X{10 + i % 100}.{i // 100} Y{20 + i % 7} F3000" for i in range(count)]


class Timed(list[str]):
    """The printer's list of commands carried out, noting the virtual time of each."""

    def __init__(self, clock: Clock) -> None:
        super().__init__()
        self.clock = clock
        self.times: list[float] = []

    def append(self, command: str) -> None:
        super().append(command)
        self.times.append(self.clock.now)


class VirtualLink:
    """The core wired to a virtual printer: job lines fed eight ahead, ticks on time."""

    def __init__(self, lines: list[str]) -> None:
        self.clock = Clock()
        self.core = LinkCore(replace(StreamerConfig(), probe_after_s=0.5))
        self.printer = VirtualPrinter(SimulatorConfig(time_scale=0.0, baud=0), self.clock,
                                      self._on_line, exec_s=EXEC_S)
        self.executed = self.printer.executed = Timed(self.clock)
        self.connected = False
        self.lines = lines
        self.queued = 0
        self.acked: list[str] = []  # job lines acknowledged, in order
        self.failure: str | None = None
        self.core.begin_connect(0.0)
        self.printer.power_on()
        self.interval = self.core.tick_interval()
        self.clock.at(self.interval, self._tick)

    def _handle(self, events: list[object]) -> None:
        for event in events:
            if isinstance(event, Acked) and event.job and event.command not in CONTROL:
                self.acked.append(event.command)
            elif isinstance(event, Connected):  # the link's own handshake is done
                self.connected = True
            elif isinstance(event, Failed):
                self.failure = event.reason

    def pump(self) -> None:
        """Queue job lines (once connected) and write what the core hands out."""
        core = self.core
        if self.connected:  # as the shell does: queued even while paused, the core holds them
            while len(core.writer.pending) < 8 and self.queued < len(self.lines):
                core.queue_job(self.lines[self.queued], self.queued)
                self.queued += 1
        while (data := core.next_bytes(self.clock.now)) is not None:
            self.printer.write(data)
        self._handle(core.take_events())

    def _on_line(self, text: str) -> None:
        self._handle(self.core.feed(text, self.clock.now))
        self.pump()

    def _tick(self) -> None:
        self._handle(self.core.tick(self.clock.now))
        self.pump()
        self.clock.at(self.clock.now + self.interval, self._tick)

    def run_until(self, done: Callable[[], bool], within_s: float) -> None:
        """Advance the clock event by event until ``done()``; fail past ``within_s``."""
        limit = self.clock.now + within_s
        while not done():
            assert self.failure is None, self.failure
            assert self.clock.now <= limit, f"not done by t={limit:.1f} s"
            self.clock.step()

    def job_commands(self) -> list[str]:
        """What the printer carried out, the link's own lines left out, with their times."""
        return [c for c in self.executed if c.split()[0] not in INTERNAL]

    def job_times(self) -> list[float]:
        return [t for c, t in zip(self.executed, self.executed.times, strict=True)
                if c.split()[0] not in INTERNAL]


def test_a_paused_link_sends_no_job_line_for_two_virtual_minutes_then_resumes_in_place() -> None:
    lines = job(300)
    link = VirtualLink(lines)
    link.run_until(lambda: len(link.acked) >= 100, 60.0)

    link.core.pause(PARK)
    link.pump()
    # every line written before the pause is carried out, and the lift after them
    link.run_until(link.core.settled, 10.0)
    paused_at = link.clock.now
    done_at_pause = len(link.job_commands())
    link.run_until(lambda: link.clock.now >= paused_at + PAUSE_S, PAUSE_S + 1.0)
    resumed_at = link.clock.now

    # two virtual minutes passed, the link alive and polling, and not one job line ran
    assert resumed_at - paused_at >= PAUSE_S
    assert len(link.job_commands()) == done_at_pause
    assert link.core.stats.probes + sum(
        c.startswith("M105") for c in link.executed) > 0
    assert link.failure is None

    for command in UNPARK:
        link.core.queue_control(command, internal=False)
    link.core.resume()
    link.pump()
    link.run_until(lambda: len(link.acked) == len(lines) and link.core.settled(), 60.0)

    body = link.job_commands()
    cut = body.index("G91")
    assert 100 <= cut < len(lines)
    assert body[cut:cut + 3] == PARK
    assert body[cut + 3:cut + 6] == UNPARK
    assert body[:cut] + body[cut + 6:] == lines
    assert link.acked == lines
    # read off the clock: the lift ran before the pause settled, nothing until the
    # resume, and the job went on from there
    times = link.job_times()
    assert times[cut + 2] <= paused_at
    assert all(t < paused_at or t >= resumed_at for t in times)
    assert times[cut + 3] >= resumed_at
    assert times[cut + 6] >= times[cut + 5]
