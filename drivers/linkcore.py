"""The printer link's protocol core: pure state machine, no I/O, time passed in.

``LinkCore`` is fed every line the printer sends (``feed(text, now)``), asked for the next
bytes to write (``next_bytes(now)``) and ticked (``tick(now)``); each returns, or queues in
``take_events()``, what the shell must do: resolve waiters, report, fail. Reading is here;
writing is in :mod:`drivers.linkwrite`, timers in :mod:`drivers.linkwatch`.
"""

from __future__ import annotations

import re
from collections import deque

from drivers.linkconfig import StreamerConfig, StreamStats
from drivers.linkevents import (
    Acked,
    Event,
    Failed,
    LinkState,
    Probed,
    Report,
    Started,
    Temperature,
)
from drivers.linkmodel import PrinterModel
from drivers.linkoks import Acknowledging
from drivers.linkresync import Resync
from drivers.linkwatch import Watching
from drivers.linkwrite import Control, Renumber, Writing
from drivers.numbering import NumberingProbe
from drivers.resend import edit_distance, recover
from drivers.responses import Response, parse_response
from drivers.window import InFlight, SendWindow

# Marlin's echo of a line it ran as an unknown command, and the rest of it for one of our
# framed lines whose leading N noise turned into another character (its checksum may be
# stripped from the echo)
_UNKNOWN = 'echo:unknown command: "'
_GARBLED_N = re.compile(r'\s*[^\d\s"](\d+)\D')  # (the blank after it may be garbled too)

# most oks awaited for an M110 written several times
MAX_LATE_OKS = 8


class LinkCore(Acknowledging, Resync, Writing, Watching):
    """Everything the link knows and decides, as plain data; see the module docstring."""

    def __init__(self, config: StreamerConfig | None = None) -> None:
        """A core in ``DISCONNECTED`` state, nothing queued."""
        self.config = config or StreamerConfig()
        self.stats = StreamStats()
        self.capabilities: dict[str, str] = {}
        self.firmware = ""
        self.acked = 0
        self.state = LinkState.DISCONNECTED
        self.error: str | None = None
        self.window = SendWindow(self.config.rx_buffer, self.config.bufsize)
        self.model = PrinterModel()
        self.history: dict[int, tuple[str, bool]] = {}
        self.next_number = 1
        self.replay_next: int | None = None
        self.last_acked_number = 0
        self.control: deque[Control] = deque()
        self.pending: deque[tuple[str, int]] = deque()
        self.renumber: Renumber | None = None
        self.paused = False
        self.cancelled = False
        self.stopping = False  # M112 queued or written: no job line goes after it
        self.resolving = False  # a probe after a refusal is out: no job line until answered
        self.doubt = False  # an answer taken for an owed one may have been a probe's in flight
        self.started = False
        self.handshaking = False
        self.last_rx = 0.0  # any line received
        self.last_answer = 0.0  # a line that answers the link (not an auto-report)
        self.last_poll = 0.0
        self.probes_unanswered = 0
        self.reports_unanswered = 0  # auto-reports since the last answer
        self.last_probe_at = -1.0  # when the last probe was due and sent
        self.over_budget = 0  # lines past the modelled receive buffer since the last answer
        self.reconnected_at = 0.0
        self.connect_at = 0.0  # when the port was opened (``begin_connect``)
        self._events: list[Event] = []
        self._plain_oks: dict[str, Response] = {}  # parsed once: plain and advanced oks
        self._oks_lost = False  # the port was cut: oks are counted in the window's order
        self._expect_resend_ok = False
        self._last_error: Response | None = None  # a line error just before this line
        self._emitted_through = 0
        self._waiters: dict[int, int] = {}  # line number -> token of a replayed control line
        self._late_oks = 0  # oks of M110s written again, still to come and not counted
        self._answers_owed: list[int] = []  # probes acknowledged ahead of their answers
        self.advanced_ok = False
        self.transcript: list[str] | None = None  # when a list, every line received goes in
        self.numbering_probe: NumberingProbe | None = None  # out before the handshake
        self.init_resync()

    # -- the shell's side -----------------------------------------------------------------

    def take_events(self) -> list[Event]:
        """Events produced since the last call, oldest first."""
        events, self._events = self._events, []
        return events

    @property
    def capable(self) -> frozenset[str]:
        """Names of the capabilities the firmware reported as enabled (``Cap:NAME:1``)."""
        return frozenset(k for k, v in self.capabilities.items() if v == "1")

    def idle(self) -> bool:
        """Nothing in flight, queued for the link's own use, replaying or renumbering."""
        return (not len(self.window) and not self.control
                and self.replay_next is None and self.renumber is None)

    def settled(self) -> bool:
        """Idle, and a probe written after every other line has been answered: every line
        written is known taken (an ok count alone can be off after noise), so a job may
        end or the numbering restart. If not, a probe is queued to find out."""
        if not self.idle():
            return False
        if not self.fenced and not any(c.probe for c in self.control):
            self.queue_control("M105", internal=True, probe=True)
        return self.fenced

    def alive(self) -> bool:
        """False once the link failed or the printer halted."""
        return self.state not in (LinkState.ERROR, LinkState.HALTED)

    def feed(self, text: str, now: float) -> list[Event]:
        """One line received from the printer (without its line ending)."""
        self.last_rx = now
        if self.transcript is not None:
            self.transcript.append(text)
        response = self._plain_oks.get(text)
        if response is None:
            response = recover(parse_response(text))
            if response.kind == "ok" and not response.temperatures \
                    and len(self._plain_oks) < 16:
                self._plain_oks[text] = response  # the same few texts, line after line
            if self.is_report(response):
                self.reports_unanswered += 1  # a sign of a powered board, not of a live link
            else:
                self.answered(now)
        else:
            self.answered(now)
        self.handle(response, now)
        if not self._events:
            return []
        return self.take_events()

    def fail(self, reason: str) -> None:
        """The link is dead: ``ERROR``, and every waiter fails."""
        if not self.alive():
            return
        self.state = LinkState.ERROR
        self.error = reason
        self.report(reason)
        self.fail_waiters(reason)

    def halt(self, reason: str) -> None:
        """The printer stopped (kill, emergency stop): ``HALTED``, every waiter fails."""
        self.state = LinkState.HALTED
        self.error = reason
        self.fail_waiters(reason)

    def fail_waiters(self, reason: str) -> None:
        """Drop everything queued; the shell fails every waiter it holds."""
        self.pending.clear()
        self.control.clear()
        self._waiters.clear()
        self._events.append(Failed(reason))

    def report(self, text: str) -> None:
        """Tell the user (``on_error``)."""
        self._events.append(Report(text))

    # -- reading --------------------------------------------------------------------------

    def handle(self, response: Response, now: float) -> None:
        """Act on one classified response."""
        probe = self.numbering_probe
        if probe is not None:
            taken = probe.take(response)
            if taken or probe.done:
                self._events.append(Probed())
            if taken:  # its answer is no line's of ours
                if response.temperatures:
                    self._events.append(Temperature(response))
                return
        kind = response.kind
        if kind == "other":
            # unreadable noise (a Resend garbled beyond repair): keep what came before;
            # an unknown command's echo with its "echo:" garbled still marks its ok
            self._on_echo(response)
            return
        after_resend = self._expect_resend_ok
        self._expect_resend_ok = False
        error_before = self._last_error
        self._last_error = None
        renumber = self.renumber
        if error_before is not None and renumber is not None and renumber.writes \
                and kind != "resend" and not (kind == "ok" and self.config.ok_after_resend):
            # a refusal whose Resend was lost to noise, the next readable line come instead
            # (an answer, or a busy echo of the next write): one write of the M110 answered
            # (an earlier one: nothing else answers before the silence that writes it
            # again), so one ok fewer is still to come. (An ok on a firmware that sends one
            # after a Resend is that ok: ``on_lost_resend`` counts the refusal.)
            renumber.refusals += 1
        if kind == "ok":
            if response.temperatures:
                self._events.append(Temperature(response))
            if after_resend:
                return  # the ok Marlin 2.1 sends after every Resend
            if error_before is not None and self.config.ok_after_resend:
                self.on_lost_resend(error_before)  # this is the ok after it
                return
            self._on_ok(response)
        elif kind == "resend":
            self._expect_resend_ok = error_before is not None and self.config.ok_after_resend
            self.on_resend(response, error_before)
        elif kind == "error":
            self._on_error(response)
        elif kind == "temperature":
            self._events.append(Temperature(response))
        elif kind == "echo":
            self._on_echo(response)
        elif kind == "capability":
            if response.name == "FIRMWARE_NAME":
                self.firmware = response.value
            else:
                self.capabilities[response.name] = response.value
        elif kind == "start":
            self._on_start()

    def _on_echo(self, response: Response) -> None:
        raw = response.raw
        head = raw[: len(_UNKNOWN)]
        if len(head) < len(_UNKNOWN) or (head[5] not in "uU" and head[:5] != "echo:"):
            return  # (fast path: most echoes and noise are nothing of the kind)
        if edit_distance(head.lower(), _UNKNOWN) > 1:
            return  # one character changed by noise is still the same message
        body = raw[len(_UNKNOWN):]
        renumber = self.renumber
        if renumber is not None:
            # after a reset the M110 is the only line written, but the rest of a line
            # written while the board booted (its N lost) may still run as an unknown
            # command: that ok is nobody's, an M110's echo (whatever noise did to its
            # digits, "\x0e9r M110 N92", or to the M110 in it when the value after it is
            # intact) is left to the renumbering, which counts one ok per write of it.
            # Either taken for the other, the count went a line off: a reset then
            # replayed a line that ran, or lost one
            words = body.split(maxsplit=3)
            is_m110 = "M110" in body or (
                len(words) > 2 and edit_distance(words[1], "M110") <= 1
                and words[2].split("*")[0].rstrip('"') == f"N{renumber.value}")
            if not is_m110:
                self._expect_resend_ok = True
            return
        if "M110" in body:
            return
        garbled = _GARBLED_N.match(raw, len(_UNKNOWN))
        rests = body.split(maxsplit=1)[1:]  # after the first word ("O>4 G1 ...": a digit hit)
        if garbled:
            rests.append(raw[garbled.end():])
        if (garbled and int(garbled.group(1)) in self.history) or any(
                self._recent_command(rest.split("*")[0].rstrip('"').strip()) for rest in rests):
            # a line of ours whose leading N was garbled ran as an unknown command; its ok
            # belongs to no line of ours (the line is refused by number later). An M110 is
            # left alone: renumbering counts one ok per write of it, and one that did not
            # take shows as refused lines, which renumber again
            self._expect_resend_ok = True
            oldest = self.window.oldest()
            if garbled and oldest is not None and oldest.number == int(garbled.group(1)) \
                    and len(self.window) == 1:
                # the only line in flight did not run as itself: the printer still needs
                # it. Replayed now, as a refusal would have it; left to the next line's
                # refusal, it waited for a probe when it was the only line the window
                # allowed. (With lines behind it, those are refused by number, and a
                # replay now would land in a receive buffer nothing drained)
                self.replay_from(oldest.number)

    def _recent_command(self, text: str) -> bool:
        """Whether ``text`` is the command of one of the last lines written (an echo whose
        line number noise changed too, ``F198 G1 ...`` for line 118, names it so)."""
        history = self.history
        top = self.next_number - 1
        return any(history.get(n, ("",))[0] == text for n in range(top, max(0, top - 64), -1))

    def _on_start(self) -> None:
        if self.state == LinkState.CONNECTING and not self.handshaking:
            if not self.started:
                self.started = True
                self._events.append(Started())
        elif self.state == LinkState.RECONNECTING:
            self.state = LinkState.PAUSED if self.paused else LinkState.READY
            self.on_reset()
        else:
            self.on_reset()

    def _completes_renumber(self, entry: InFlight) -> bool:
        renumber = self.renumber
        return (renumber is not None and renumber.sent and entry.number == renumber.line
                and entry.command.startswith("M110"))

    def _finish_renumber(self) -> None:
        """The printer took the ``M110``: continue in the numbering it set (every record
        kept by line number is set for it here)."""
        renumber = self.renumber
        assert renumber is not None
        value, keep = renumber.value, renumber.keep_history
        self.renumber = None
        if renumber.token is not None:
            self._events.append(Acked(value, f"M110 N{value}", False, renumber.token))
        self.clear_resync()
        if keep and value + 1 < self.next_number:
            self.replay_next = value + 1
        else:
            self.history.clear()
            self.next_number = value + 1
            self.replay_next = None
            self.force_replay = False
            self._emitted_through = value
            self.forget_requests()  # requests counted against the old numbers
        self.last_acked_number = value
        self._oks_lost = False  # the count restarts from the M110
        self.model.renumbered(value)
        # an M110 written again after silence may have its first ok still to come, before
        # any ok of the lines that follow: those oks are not counted for them
        self._late_oks = min(renumber.late_oks(), MAX_LATE_OKS)

    def _on_error(self, response: Response) -> None:
        self.stats.errors += 1
        if response.error_kind in ("checksum", "line_number", "no_checksum", "no_line_number"):
            self._last_error = response
            return
        if response.error_kind in ("halted", "stopped"):
            self.report(response.text)
            self.halt(f"printer stopped: {response.text}")
            self.error = response.text
            return
        self.report(response.text)

    def on_lost_resend(self, error: Response) -> None:
        """An ``Error`` then its ``ok``, the ``Resend`` between them lost to noise: act on
        the request the error implies (the line after its ``Last Line``), so that a refused
        ``M110`` counts as refused and a refused line is replayed."""
        digits = str(error.line + 1) if error.line is not None else ""
        implied = Response("resend", f"Resend: {digits}",
                           line=error.line + 1 if error.line is not None else None,
                           digits=digits)
        self.on_resend(implied, error, implied=True)
        self._expect_resend_ok = False  # its ok is the one being read

    def on_reset(self) -> None:
        """``start`` mid-stream: the printer rebooted and lost its buffers and line number."""
        self.stats.resets += 1
        self.forget_requests()  # requests seen before the reboot confirm nothing after it
        if self.renumber is None:
            value = self.last_acked_number
            self.renumber = Renumber(value, value, keep_history=True, quiet=True)
        self.forget_in_flight()
        self.model.lost()

    def forget_in_flight(self) -> None:
        """Whatever was on the wire or in the printer's buffers is gone (reset or cut):
        nothing in flight, no replay under way, an ``M110`` in progress to be written anew."""
        self.window.clear()
        self.clear_resync()
        self.replay_next = None
        self.force_replay = False
        self.resolving = False
        self.doubt = False
        self._late_oks = 0
        self._answers_owed = []
        if self.renumber is not None:
            self.renumber.sent = False
            self.renumber.writes = self.renumber.refusals = 0

    def remember_waiter(self, number: int, token: int) -> None:
        """A control line's waiter, found again by number when the line is replayed."""
        self._waiters[number] = token

    # -- connection -------------------------------------------------------------------------

    def retune(self, config: StreamerConfig) -> None:
        """New settings (firmware defaults chosen at connect): buffers apply at once."""
        self.config = config
        self.window.max_bytes = config.rx_buffer
        if config.bufsize > self.window.max_lines or not self.advanced_ok:
            self.window.max_lines = max(config.bufsize, 1)
        self.window.limit = self.window.max_lines

    def begin_connect(self, now: float) -> None:
        """The port is open: wait for ``start`` (the board's reset)."""
        self.state = LinkState.CONNECTING
        self.last_rx = self.last_answer = self.connect_at = now

    def begin_handshake(self, reset_to: int, keep_history: bool, token: int) -> None:
        """``M110 N<reset_to>`` once nothing is in flight; ``token`` is acknowledged when
        the printer took it."""
        self.handshaking = True  # from now on a `start` is a reset to recover from
        # numbered as the value it sets: "N1 M110 N0" set the last line to 0 on Marlin and
        # to 1 on firmware that reads the line's own number, which then refused line 1
        self.renumber = Renumber(reset_to, reset_to, keep_history, token=token)

    def connected(self, now: float) -> None:
        """The handshake is done: ready to stream (or paused, if paused meanwhile)."""
        self.state = LinkState.PAUSED if self.paused else LinkState.READY
        self.last_poll = now

    def link_lost(self, reason: str) -> None:
        """The port failed; the shell tries to reopen it."""
        self.state = LinkState.DISCONNECTED
        self.report(f"link lost: {reason}")

    def reopened(self, now: float) -> None:
        """The port is open again: wait for ``start`` or ``start_timeout_s``."""
        self.stats.reconnects += 1
        self.reconnected_at = self.last_rx = self.last_answer = now
        self._oks_lost = True
        self.forget_in_flight()
        self.model.lost()
        self.state = LinkState.RECONNECTING
