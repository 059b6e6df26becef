"""The protocol core's liveness: which lines answer it, probes, polls, reconnect waits."""

from __future__ import annotations

import math

from drivers.linkconfig import LONG_COMMANDS
from drivers.linkevents import Event, LinkState, Started
from drivers.linkfields import CoreFields
from drivers.protocol import frame
from drivers.responses import Response

# silence after which a probe goes when a line the printer has read may never get its ok
# (a refusal named it as the last line; some firmware's ok after the Resend stood in for
# it), while a refusal's probe is unanswered or a replay waits for room: the window may
# then wait for an ok that never comes, so the link asks at once rather than after
# ``probe_after_s`` (one such probe per silence)
HELD_PROBE_S = 0.1

# commands that wait for a heater and report temperatures while they run
HEATING = frozenset({"M109", "M190", "M191", "M303"})


class Watching(CoreFields):
    """Mixin of :class:`~drivers.linkcore.LinkCore`: what time alone decides."""

    def is_report(self, response: Response) -> bool:
        """True for a line the printer sends on its own (``M155`` temperature, ``M154``
        position auto-reports), which answers nothing the link asked: a board that sends
        only those is not running what it is sent. A heating wait's report (``W:``, or any
        temperature line while ``M109``/``M190``/``M191``/``M303`` is in flight) is the
        running command's own output and keeps the link alive."""
        kind = response.kind
        if kind == "temperature":
            if " W:" in response.raw:
                return False
            return not any(e.command.split(" ", 1)[0] in HEATING for e in self.window)
        return kind == "other" and response.raw.startswith("X:")

    def answered(self, now: float) -> None:
        """The printer answered something: the silence that probes measure restarts."""
        self.last_answer = now
        self.probes_unanswered = 0
        self.reports_unanswered = 0
        self.over_budget = 0

    def tick_interval(self) -> float:
        """How often the shell should call :meth:`tick` (seconds)."""
        tick = min(0.25, self.config.probe_after_s / 4, HELD_PROBE_S / 2)
        if self.config.temperature_interval_s > 0:
            tick = min(tick, self.config.temperature_interval_s / 4)
        return tick

    def tick(self, now: float) -> list[Event]:
        """Let time pass: probes, polls, give-ups. Returns the events produced."""
        if self.state in (LinkState.ERROR, LinkState.HALTED, LinkState.DISCONNECTED):
            return self.take_events()
        if self.state == LinkState.RECONNECTING:
            self._watch_reconnect(now)
        elif self.state == LinkState.CONNECTING and not self.started:
            self._watch_start(now)
        else:
            self._watch_silence(now)
            self._watch_temperature(now)
        return self.take_events()

    def _watch_start(self, now: float) -> None:
        """No ``start`` banner within ``start_timeout_s`` of opening the port: a board that
        did not reset on open (or prints no banner) is taken as ready (``Started``)."""
        if now - self.connect_at >= self.config.start_timeout_s:
            self.started = True
            self._events.append(Started())

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
            if now - max(self.last_answer, renumber.sent_at) >= self.config.renumber_retry_s:
                self.window.clear()  # M110 is idempotent: write it again
                renumber.sent = False
                self.probes_unanswered += 1
                self.stats.probes += 1
                if self.probes_unanswered > self.config.probe_retries:
                    self.fail("printer does not answer M110" + self._reports_note())
            return
        if not len(self.window):
            return
        # silence: nothing that answers the link (auto-reports answer nothing); one probe
        # per interval at most, each only when it fits the receive buffer as modelled
        silence = now - self.last_answer
        interval = self.config.probe_after_s
        unsure = self.window.held or self.doubt or self.resolving \
            or self.replay_next is not None  # (a replay the window holds back)
        if unsure and interval > HELD_PROBE_S \
                and not self.probes_unanswered:  # (one such probe: no storm of them)
            interval = HELD_PROBE_S
        if silence < interval * (self.probes_unanswered + 1) \
                or now - self.last_probe_at < interval:
            return
        long_running = any(e.command.split(" ", 1)[0] in LONG_COMMANDS for e in self.window)
        if long_running:
            if silence >= self.config.long_command_timeout_s:
                self.fail(f"printer silent for {silence:.0f} s during a long command"
                          + self._reports_note())
            elif self.probes_unanswered == 0 and not self._awaiting_room(now):
                self.probe(now)
            return
        if self.probes_unanswered >= self.config.probe_retries:
            self.fail(f"printer not responding ({self.probes_unanswered} probes unanswered"
                      f"{self._reports_note(', ')})")
            return
        if not self._awaiting_room(now):
            self.probe(now)

    def _reports_note(self, sep: str = "; ") -> str:
        count = self.reports_unanswered
        return f"{sep}{count} auto-reports meanwhile" if count else ""

    def _awaiting_room(self, now: float) -> bool:
        """True while the next line past the window (a probe, or the replay's next line)
        may not go yet (:meth:`may_force`): the probe waits, not counted as unanswered."""
        number = self.replay_next
        held = self.history.get(number) if number is not None else None
        if number is not None and held is not None:
            nbytes = len(frame(number, held[0]))
        else:
            nbytes = len(frame(self.next_number, "M105"))
        return not self.may_force(nbytes, now, take=False)

    def may_force(self, nbytes: int, now: float, take: bool = True) -> bool:
        """Whether a line of ``nbytes`` may go past the window now (a probe, a replayed line
        after silence), and if so (``take``) record it.

        Only when it fits the printer's receive buffer as modelled (every byte written and
        not acknowledged is in it), or, for a buffer the model says full, once the silence
        is long (a probe interval, and ``busy_silence_s``: two of Marlin's 2 s keep-alive
        intervals) and then as it doubles: a second line past the model after twice that
        silence, a third after four times... Lost oks leave the model full while the printer
        holds nothing: a probe must go, and its answer sets the count right; a printer
        holding half a line (its end lost) needs bytes to answer at all. But Marlin reads
        its receive buffer only from its main loop, which does not run while a command
        blocks (a move waiting for room in a full planner): there, one line per interval
        fills the 128 bytes in a dozen intervals and overruns them (bytes lost, a probe
        merged with the next line, its checksum matching by chance: a line not run as
        written). A blocked Marlin with ``HOST_KEEPALIVE_FEATURE`` (on by default) says
        ``busy:`` every 2 s, so a longer silence means a printer that is not blocked, or a
        build without it, which then gets a few lines past the model in any silence, not one
        per interval.
        """
        if self.window.bytes_in_flight + nbytes <= self.window.max_bytes:
            return True
        silence = now - self.last_answer
        quiet = max(self.config.probe_after_s, self.config.busy_silence_s)
        allowed = int(math.log2(silence / quiet)) + 1 if silence >= quiet else 0
        if self.over_budget >= allowed:
            return False
        if take:
            self.over_budget += 1
        return True

    def probe(self, now: float) -> None:
        """Ask ``M105`` past the window: its ``ok T:`` proves every earlier line done.

        One probe at a time: one already queued is only made urgent. It goes out only when
        :meth:`may_force` allows.
        During a replay the probe waits for the replay to end, numbered after it (a probe
        numbered ahead would be refused), and the replay passes the window meanwhile.
        """
        self.probes_unanswered += 1
        self.stats.probes += 1
        self.last_probe_at = now
        if now - self.last_answer >= self.config.busy_silence_s:
            # answers still owed to probes did not come in a long silence: withheld (a
            # firmware whose ok after a Resend stood for the probe's). Still awaited, they
            # swallowed the answer of every probe after them, and the link probed for ever
            self._answers_owed = []
        if self.replay_next is not None:
            self.force_replay = True
        queued = next((c for c in self.control if c.probe), None)
        if queued is None:
            self.queue_control("M105", internal=True, probe=True, force=True)
            queued = self.control.pop()
        else:
            queued.force = True
            self.control.remove(queued)
        # ahead of the lines waiting for room in the window (park or end G-code, a user's
        # command): when the count holds room the printer has freed (oks lost), only a
        # probe's answer frees it, and a probe behind them was never written (the link
        # then declared a printer that answered every line dead)
        at = next((k for k, c in enumerate(self.control) if not c.force), len(self.control))
        self.control.insert(at, queued)

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
