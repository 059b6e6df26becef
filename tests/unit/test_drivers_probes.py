"""Probes after silence on a virtual clock: never into a full receive buffer, still finding
lost oks, and a printer that only auto-reports declared dead. No real time passes."""

from __future__ import annotations

import math

from support.linkcores import connected_core
from support.linkrun import run_core

from drivers.link.config import StreamerConfig
from drivers.link.core import LinkCore
from drivers.link.events import Booted, Failed, LinkState, Report
from drivers.sim.config import SimulatorConfig
from drivers.sim.virtual import VirtualPrinter

# the pty tests' and the stall harness's short probe interval: silence comes quickly
LINK = StreamerConfig(temperature_interval_s=0, probe_after_s=0.02, probe_retries=1000,
                      resync_quiet_s=0.01)
REPORT = "T:20.00 /0.00 B:20.00 /0.00 @:0 B@:0"


def wire(**kw) -> SimulatorConfig:
    """A 250000-baud board with 1 ms of latency each way, fast boot."""
    base = {"baud": 250000, "latency_s": 0.001, "keepalive_s": 0.05, "boot_delay_s": 0.05}
    return SimulatorConfig(**{**base, **kw})


def long_lines(n: int) -> list[str]:
    """``n`` distinct moves of about 60 framed bytes: two fill the 127-byte window, with
    no room for a probe beside them."""
    return [f"G1 X{100 + 40 * math.cos(0.01 * i):.5f} Y{100 + 40 * math.sin(0.01 * i):.5f}"
            f" Z0.20000 E{0.01 + 1e-5 * i:.6f} F1800.0" for i in range(n)]


class SlowMoves(VirtualPrinter):
    """Each ``G1`` blocks the queue for ``move_s`` (a long move, the planner full, no busy
    keepalive); the oks of the moves in ``lose`` are lost on the wire."""

    move_s = 1.0
    lose: frozenset[str] = frozenset()
    _losing = False

    def _start_next(self) -> None:
        self.exec_s = self.move_s if self._queue[0][0].startswith("G1") else 0.0
        super()._start_next()

    def _finish(self, boot: int) -> None:
        self._losing = bool(self._queue) and self._queue[0][0] in self.lose
        super()._finish(boot)

    def _ok(self, suffix: str = "") -> None:
        if self._losing:
            self._losing = False
            return
        super()._ok(suffix)


def test_a_full_receive_buffer_and_a_long_silence_never_overrun_it():
    # each move holds the queue for 2 s, 100 probe intervals: the probes of the silence
    # used to go past the window one per interval, into the 128-byte receive buffer, and
    # an overrun merged one with the next line (its checksum still matching, about once
    # in 400 runs of the stall harness)
    lines = long_lines(12)

    class Printer(SlowMoves):
        move_s = 2.0

    run = run_core(lines, wire(), LINK, printer_class=Printer, max_seconds=600)
    assert run.printer.overrun_bytes == 0
    assert run.printer.errors == 0
    assert run.executed == lines
    assert run.acked == lines
    assert run.stats.probes > 0  # probes were due, and went out when they fitted


def test_lost_oks_with_a_full_window_on_a_slow_printer_still_finish_exactly_once():
    # the window full (two long lines), every ok of it lost, at the end of the job and in
    # its middle: the ok count says the receive buffer is full while the printer holds
    # nothing, so a probe only within the budget would never go; after longer silence
    # the oldest lines are credited as read, one per interval, and the probe goes
    lines = long_lines(24)

    class Printer(SlowMoves):
        move_s = 0.5
        lose = frozenset(lines[10:12] + lines[-2:])

    run = run_core(lines, wire(), LINK, printer_class=Printer, max_seconds=600)
    assert run.printer.overrun_bytes == 0
    assert run.executed == lines
    assert run.acked == lines


def _written(core: LinkCore, now: float) -> list[str]:
    out = []
    while (data := core.next_bytes(now)) is not None:
        out.append(data.decode())
    return out


def test_a_printer_that_only_auto_reports_is_declared_dead_within_the_probes_allowed():
    # M155 reports every 10 ms keep coming, nothing else: the board is powered but runs
    # nothing it is sent. Every report used to reset the unanswered probes: probed for ever
    config = StreamerConfig(temperature_interval_s=0, probe_after_s=0.05, probe_retries=3)
    core = connected_core(config)
    for i in range(10):
        core.queue_job(f"G1 X{i}", 10 + i)
    written = _written(core, 0.01)
    events = []
    t = 0.01
    while core.alive() and t < 10.0:
        t += 0.01
        events += core.feed(REPORT, t)
        events += core.tick(t)
        written += _written(core, t)
    assert core.state is LinkState.ERROR
    assert t < 1.0  # within a few probe intervals, not after any long timeout
    probes = [w for w in written if "M105" in w]
    assert 1 <= len(probes) <= config.probe_retries
    reports = [e.text for e in events if isinstance(e, Report)]
    assert reports  # reported, not silently dropped
    assert "not responding" in reports[-1]
    assert "auto-reports" in reports[-1]
    assert any(isinstance(e, Failed) for e in events)


def test_a_long_heating_wait_with_temperature_lines_is_not_declared_dead():
    # M109 for two minutes: a report each second, with Marlin's W: or (another firmware)
    # without it; nothing else. Far longer than probes and the long-command timeout allow
    # for silence, but the running command's own output keeps the link alive
    config = StreamerConfig(temperature_interval_s=0, probe_after_s=0.05, probe_retries=2,
                            long_command_timeout_s=3.0)
    for wait in (" W:?", ""):
        core = connected_core(config)
        core.queue_job("M109 S210", 10)
        core.queue_job("G1 X1", 11)
        events = []
        for step in range(1, 2400):  # 50 ms steps
            t = 0.01 + step * 0.05
            if step % 20 == 0:
                events += core.feed(f"T:{min(210.0, 20 + t * 2):.2f} /210.00 B:20.00 /0.00"
                                    f" @:127 B@:0{wait}", t)
            events += core.tick(t)
            _written(core, t)
        assert not [e for e in events if isinstance(e, Failed | Report)]
        assert core.alive()
        core.feed("ok", t)  # the M109 done, then the move
        core.feed("ok", t)
        assert core.acked == 2


def test_every_boot_banner_is_an_event_of_the_core():
    # the daemon's boot watch is the link's (Streamer.on_boot): the banner at connect and a
    # reboot mid-stream each give one Booted, and nothing else does
    core = LinkCore(StreamerConfig(temperature_interval_s=0))
    core.begin_connect(0.0, identify=False)
    assert [e for e in core.feed("start", 0.0) if isinstance(e, Booted)] == [Booted()]
    assert core.next_bytes(0.0) == b"\n"
    core.next_bytes(0.0)  # the handshake's M110
    assert not any(isinstance(e, Booted) for e in core.feed("ok", 0.001))
    core.queue_job("G1 X1", 1)
    assert core.next_bytes(0.002) is not None
    assert not any(isinstance(e, Booted) for e in core.feed("echo:start of a message", 0.003))
    assert [e for e in core.feed("start", 0.004) if isinstance(e, Booted)] == [Booted()]
    assert core.stats.resets == 1  # (and the core recovers from it as before)
