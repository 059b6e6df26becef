"""The protocol core's watchdog: which lines answer it, probes, polls, reconnect waits.

:class:`Watchdog` owns the link's clocks (when a line last came, when one last answered
the link, when the port was opened or reopened, the last poll and probe) and what it
counts of the silence (probes unanswered, auto-reports meanwhile, lines let past the
modelled receive buffer). The core (:class:`~drivers.link.core.LinkCore`) holds it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from drivers.link.config import LONG_COMMANDS
from drivers.link.events import Event, LinkState
from drivers.link.protocol import frame
from drivers.link.responses import Response

if TYPE_CHECKING:  # the core holds the watchdog; the watchdog asks it (one-way at run time)
    from drivers.link.core import LinkCore

# silence after which a probe goes when a line the printer has read may never get its ok
# (a refusal named it as the last line; some firmware's ok after the Resend stood in for
# it), while a refusal's probe is unanswered or a replay waits for room: the window may
# then wait for an ok that never comes, so the link asks at once rather than after
# ``probe_after_s`` (one such probe per silence)
HELD_PROBE_S = 0.1

# commands that wait for a heater and report temperatures while they run
HEATING = frozenset({"M109", "M190", "M191", "M303"})


class Watchdog:
    """What time alone decides (see the module docstring)."""

    def __init__(self, core: LinkCore) -> None:
        """Clocks at zero, nothing unanswered."""
        self.core = core
        self.window = core.window
        self.stats = core.stats
        self.last_rx = 0.0  # any line received
        self.last_answer = 0.0  # a line that answers the link (not an auto-report)
        self.last_poll = 0.0
        self.probes_unanswered = 0
        self.reports_unanswered = 0  # auto-reports since the last answer
        self.last_probe_at = -1.0  # when the last probe was due and sent
        self.over_budget = 0  # lines past the modelled receive buffer since the last answer
        self.reconnected_at = 0.0
        self.connect_at = 0.0  # when the port was opened (``begin_connect``)

    def heard(self, now: float, response: Response, fast: bool) -> None:
        """A line received; ``fast``: a plain ok seen before (it answers the link)."""
        self.last_rx = now
        if fast:  # (answered, inline: once per plain ok)
            self.last_answer = now
            self.probes_unanswered = self.reports_unanswered = self.over_budget = 0
        elif self.is_report(response):
            self.reports_unanswered += 1  # a sign of a powered board, not of a live link
        else:
            self.answered(now)

    def opened(self, now: float) -> None:
        """The port was opened: the start banner's wait begins."""
        self.last_rx = self.last_answer = self.connect_at = now

    def reopened(self, now: float) -> None:
        """The port was opened again after it was lost."""
        self.reconnected_at = self.last_rx = self.last_answer = now

    def polled(self, now: float) -> None:
        """The handshake is done: temperature polls from now."""
        self.last_poll = now

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
        tick = min(0.25, self.core.config.probe_after_s / 4, HELD_PROBE_S / 2)
        if self.core.config.temperature_interval_s > 0:
            tick = min(tick, self.core.config.temperature_interval_s / 4)
        return tick

    def tick(self, now: float) -> list[Event]:
        """Let time pass: probes, polls, give-ups. Returns the events produced."""
        if self.core.state in (LinkState.ERROR, LinkState.HALTED, LinkState.DISCONNECTED):
            return self.core.take_events()
        if self.core.state == LinkState.RECONNECTING:
            self._watch_reconnect(now)
        elif self.core.state == LinkState.CONNECTING and not self.core.started:
            self._watch_start(now)
        else:
            if self.core.state == LinkState.CONNECTING:
                self.core.handshake.tick(now)
            self._watch_silence(now)
            self._watch_temperature(now)
        return self.core.take_events()

    def _watch_start(self, now: float) -> None:
        """No ``start`` banner within ``start_timeout_s`` of opening the port: a board that
        did not reset on open (or prints no banner) is taken as ready (``Started``)."""
        if now - self.connect_at >= self.core.config.start_timeout_s:
            self.core.start_timed_out(now)

    def _watch_reconnect(self, now: float) -> None:
        """No ``start`` after reopening: the printer kept its state; continue after the
        last acknowledged line (it refuses, by line number, anything it already has)."""
        if now - self.reconnected_at < self.core.config.start_timeout_s:
            return
        self.core.reconnect_timed_out()

    def _watch_silence(self, now: float) -> None:
        renumber = self.core.writer.renumber
        if renumber is not None and renumber.sent:
            if now - max(self.last_answer, renumber.sent_at) >= self.core.config.renumber_retry_s:
                self.core.writer.write_renumber_again()
                self.probes_unanswered += 1
                self.stats.probes += 1
                if self.probes_unanswered > self.core.config.probe_retries:
                    self.core.fail("printer does not answer M110" + self._reports_note())
            return
        if not len(self.window):
            return
        # silence: nothing that answers the link (auto-reports answer nothing); one probe
        # per interval at most, each only when it fits the receive buffer as modelled
        silence = now - self.last_answer
        interval = self.core.config.probe_after_s
        unsure = self.window.held or self.core.acks.doubt or self.core.acks.resolving \
            or self.core.writer.replay_next is not None  # (a replay the window holds back)
        if unsure and interval > HELD_PROBE_S \
                and not self.probes_unanswered:  # (one such probe: no storm of them)
            interval = HELD_PROBE_S
        if silence < interval * (self.probes_unanswered + 1) \
                or now - self.last_probe_at < interval:
            return
        long_running = any(e.command.split(" ", 1)[0] in LONG_COMMANDS for e in self.window)
        if long_running:
            if silence >= self.core.config.long_command_timeout_s:
                self.core.fail(f"printer silent for {silence:.0f} s during a long command"
                          + self._reports_note())
            elif self.probes_unanswered == 0 and not self._awaiting_room(now):
                self.probe(now)
            return
        if self.probes_unanswered >= self.core.config.probe_retries:
            self.core.fail(f"printer not responding ({self.probes_unanswered} probes unanswered"
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
        number = self.core.writer.replay_next
        held = self.core.writer.history.get(number) if number is not None else None
        if number is not None and held is not None:
            nbytes = len(frame(number, held[0]))
        else:
            nbytes = len(frame(self.core.writer.next_number, "M105"))
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
        quiet = max(self.core.config.probe_after_s, self.core.config.busy_silence_s)
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
        if now - self.last_answer >= self.core.config.busy_silence_s:
            # answers still owed to probes did not come in a long silence: withheld (a
            # firmware whose ok after a Resend stood for the probe's). Still awaited, they
            # swallowed the answer of every probe after them, and the link probed for ever
            self.core.acks.forget_owed()
        self.core.writer.urge_probe()

    def _watch_temperature(self, now: float) -> None:
        interval = self.core.config.temperature_interval_s
        if interval <= 0 or "AUTOREPORT_TEMP" in self.core.capable \
                or self.core.state == LinkState.CONNECTING:
            return
        if now - self.last_poll < interval:
            return
        self.last_poll = now
        if any(e.probe for e in self.window) or any(c.probe for c in self.core.writer.control):
            return
        self.core.writer.queue_control("M105", internal=True, probe=True)
