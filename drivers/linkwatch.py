"""The protocol core's timers: probes after silence, temperature polls, reconnect waits."""

from __future__ import annotations

from drivers.linkconfig import LONG_COMMANDS
from drivers.linkevents import Event, LinkState
from drivers.linkfields import CoreFields


class Watching(CoreFields):
    """Mixin of :class:`~drivers.linkcore.LinkCore`: what time alone decides."""

    def tick_interval(self) -> float:
        """How often the shell should call :meth:`tick` (seconds)."""
        tick = min(0.25, self.config.probe_after_s / 4)
        if self.config.temperature_interval_s > 0:
            tick = min(tick, self.config.temperature_interval_s / 4)
        return tick

    def tick(self, now: float) -> list[Event]:
        """Let time pass: probes, polls, give-ups. Returns the events produced."""
        if self.state in (LinkState.ERROR, LinkState.HALTED, LinkState.DISCONNECTED):
            return self.take_events()
        if self.state == LinkState.RECONNECTING:
            self._watch_reconnect(now)
        else:
            self._watch_silence(now)
            self._watch_temperature(now)
        return self.take_events()

    def _watch_reconnect(self, now: float) -> None:
        """No ``start`` after reopening: the printer kept its state; continue after the
        last acknowledged line (it refuses, by line number, anything it already has)."""
        if now - self.reconnected_at < self.config.start_timeout_s:
            return
        self.state = LinkState.PAUSED if self.paused else LinkState.READY
        if self.renumber is None and self.last_acked_number + 1 < self.next_number:
            self.replay_next = self.last_acked_number + 1

    def _watch_silence(self, now: float) -> None:
        renumber = self.renumber
        if renumber is not None and renumber.sent:
            if now - max(self.last_rx, renumber.sent_at) >= self.config.renumber_retry_s:
                self.window.clear()  # M110 is idempotent: write it again
                renumber.sent = False
                self.probes_unanswered += 1
                self.stats.probes += 1
                if self.probes_unanswered > self.config.probe_retries:
                    self.fail("printer does not answer M110")
            return
        if not len(self.window):
            return
        silence = now - self.last_rx
        due = self.config.probe_after_s * (self.probes_unanswered + 1)
        if silence < due:
            return
        long_running = any(e.command.split(" ", 1)[0] in LONG_COMMANDS for e in self.window)
        if long_running:
            if silence >= self.config.long_command_timeout_s:
                self.fail(f"printer silent for {silence:.0f} s during a long command")
            elif self.probes_unanswered == 0:
                self.probe()
            return
        if self.probes_unanswered >= self.config.probe_retries:
            self.fail(f"printer not responding ({self.probes_unanswered} probes unanswered)")
            return
        self.probe()

    def probe(self) -> None:
        """Ask ``M105`` past the window: its ``ok T:`` proves every earlier line done.

        One probe at a time: one already queued is only made urgent.
        During a replay the probe waits for the replay to end, numbered after it (a probe
        numbered ahead would be refused), and the replay passes the window meanwhile.
        """
        self.probes_unanswered += 1
        self.stats.probes += 1
        if self.replay_next is not None:
            self.force_replay = True
        queued = next((c for c in self.control if c.probe), None)
        if queued is not None:
            queued.force = True
            return
        self.queue_control("M105", internal=True, probe=True, force=True)

    def _watch_temperature(self, now: float) -> None:
        interval = self.config.temperature_interval_s
        if interval <= 0 or "AUTOREPORT_TEMP" in self.capable \
                or self.state == LinkState.CONNECTING:
            return
        if now - self.last_poll < interval:
            return
        self.last_poll = now
        if any(e.probe for e in self.window) or any(c.probe for c in self.control):
            return
        self.queue_control("M105", internal=True, probe=True)
