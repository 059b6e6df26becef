"""The printer link's protocol core: pure state machine, no I/O, time passed in.

``LinkCore`` is fed every line the printer sends (``feed(text, now)``), asked for the next
bytes to write (``next_bytes(now)``) and ticked (``tick(now)``); each returns, or queues in
``take_events()``, what the shell must do: resolve waiters, report, fail. Reading is here;
writing is in :mod:`drivers.link.writer`, timers in :mod:`drivers.link.watchdog`.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from drivers.link.config import StreamerConfig, StreamStats
from drivers.link.events import (
    Acked,
    Booted,
    Event,
    Failed,
    LinkState,
    Report,
    Temperature,
)
from drivers.link.handshake import Handshake
from drivers.link.model import PrinterModel
from drivers.link.oks import AckCounter
from drivers.link.resend import edit_distance, recover
from drivers.link.responses import Response, parse_response
from drivers.link.resync import Resync
from drivers.link.watchdog import Watchdog
from drivers.link.window import InFlight, SendWindow
from drivers.link.writer import LinkWriter, Renumber

# Marlin's echo of a line it ran as an unknown command, and the rest of it for one of our
# framed lines whose leading N noise turned into another character (its checksum may be
# stripped from the echo)
_UNKNOWN = 'echo:unknown command: "'
_GARBLED_N = re.compile(r'\s*[^\d\s"](\d+)\D')  # (the blank after it may be garbled too)


class LinkCore:
    """Everything the link knows and decides, as plain data; see the module docstring.

    Composed of four parts, each owning its own fields: :attr:`writer`
    (:class:`~drivers.link.writer.LinkWriter`), :attr:`acks`
    (:class:`~drivers.link.oks.AckCounter`), :attr:`resync`
    (:class:`~drivers.link.resync.Resync`) and :attr:`watchdog`
    (:class:`~drivers.link.watchdog.Watchdog`). The core itself keeps what they share: the
    settings, the counters, the window of lines in flight, the model of the printer's line
    bookkeeping, the link's state and the job's flags, and the events for the shell.
    """

    def __init__(self, config: StreamerConfig | None = None) -> None:
        """A core in ``DISCONNECTED`` state, nothing queued."""
        self.config = config or StreamerConfig()
        self.stats = StreamStats()
        self.capabilities: dict[str, str] = {}
        self.firmware = ""
        self.state = LinkState.DISCONNECTED
        self.error: str | None = None
        self.window = SendWindow(self.config.rx_buffer, self.config.bufsize)
        self.model = PrinterModel()
        self.paused = False
        self.cancelled = False
        self.stopping = False  # M112 queued or written: no job line goes after it
        self.started = False
        self.handshaking = False
        self._events: list[Event] = []
        self._plain_oks: dict[str, Response] = {}  # parsed once: plain and advanced oks
        self._expect_resend_ok = False
        self._last_error: Response | None = None  # a line error just before this line
        self.writer = LinkWriter(self)
        # the next bytes to write now (recorded as written), or None: the writer's, called
        # for every line (no call of the core's own in between)
        self.next_bytes: Callable[[float], bytes | None] = self.writer.next_bytes
        self.acks = AckCounter(self)
        self.resync = Resync(self)
        self.watchdog = Watchdog(self)
        self.handshake = Handshake(self)

    # -- what the parts tell each other through the core ----------------------------------

    def emit(self, event: Event) -> None:
        """One event for the shell (:meth:`take_events`)."""
        self._events.append(event)

    def emit_acked(self, event: Acked) -> None:
        """A line acknowledged: the handshake's own lines (negative tokens) are the
        handshake's business, every other for the shell."""
        token = event.token
        if token is not None and token < 0:
            self.handshake.acked(token)
        else:
            self._events.append(event)

    @property
    def acked(self) -> int:
        """Job lines acknowledged so far."""
        return self.acks.acked

    @property
    def next_number(self) -> int:
        """The number the next new line is written under."""
        return self.writer.next_number

    def queue_job(self, command: str, token: int) -> None:
        """A job command to write after those already queued; ``Written`` tells its number."""
        self.writer.queue_job(command, token)

    def queue_control(self, command: str, *, internal: bool, token: int | None = None,
                      probe: bool = False, force: bool = False, front: bool = False) -> None:
        """A line outside the job (:meth:`~drivers.link.writer.LinkWriter.queue_control`)."""
        self.writer.queue_control(command, internal=internal, token=token, probe=probe,
                                  force=force, front=front)


    def tick(self, now: float) -> list[Event]:
        """Let time pass: probes, polls, give-ups. Returns the events produced."""
        return self.watchdog.tick(now)

    def tick_interval(self) -> float:
        """How often the shell should call :meth:`tick` (seconds)."""
        return self.watchdog.tick_interval()

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
        return (not len(self.window) and not self.writer.control
                and self.writer.replay_next is None and self.writer.renumber is None)

    def settled(self) -> bool:
        """Idle, and a probe written after every other line has been answered: every line
        written is known taken (an ok count alone can be off after noise), so a job may
        end or the numbering restart. If not, a probe is queued to find out."""
        if not self.idle():
            return False
        if not self.writer.fenced and not any(c.probe for c in self.writer.control):
            self.writer.queue_control("M105", internal=True, probe=True)
        return self.writer.fenced

    def alive(self) -> bool:
        """False once the link failed or the printer halted."""
        return self.state not in (LinkState.ERROR, LinkState.HALTED)

    def feed(self, text: str, now: float) -> list[Event]:
        """One line received from the printer (without its line ending)."""
        transcript = self.handshake.transcript
        if transcript is not None:
            transcript.append(text)
        response = self._plain_oks.get(text)
        if response is None:
            response = recover(parse_response(text))
            if response.kind == "ok" and not response.temperatures \
                    and len(self._plain_oks) < 16:
                self._plain_oks[text] = response  # the same few texts, line after line
            self.watchdog.heard(now, response, False)
            if response.kind == "start":
                self._events.append(Booted())  # whatever it means to the protocol
        else:
            self.watchdog.heard(now, response, True)
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
        self.writer.drop_all()
        self.acks.forget_waiters()
        self._events.append(Failed(reason))

    def report(self, text: str) -> None:
        """Tell the user (``on_error``)."""
        self._events.append(Report(text))

    # -- reading --------------------------------------------------------------------------

    def handle(self, response: Response, now: float) -> None:
        """Act on one classified response."""
        if self.handshake.probe is not None and self.handshake.take(response, now):
            # its answer is no line's of ours
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
        renumber = self.writer.renumber
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
            self.acks.on_ok(response)
        elif kind == "resend":
            self._expect_resend_ok = error_before is not None and self.config.ok_after_resend
            self.resync.on_resend(response, error_before)
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
            self._on_start(now)

    def _on_echo(self, response: Response) -> None:
        raw = response.raw
        head = raw[: len(_UNKNOWN)]
        if len(head) < len(_UNKNOWN) or (head[5] not in "uU" and head[:5] != "echo:"):
            return  # (fast path: most echoes and noise are nothing of the kind)
        if edit_distance(head.lower(), _UNKNOWN) > 1:
            return  # one character changed by noise is still the same message
        body = raw[len(_UNKNOWN):]
        renumber = self.writer.renumber
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
        if (garbled and int(garbled.group(1)) in self.writer.history) or any(
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
                self.resync.replay_from(oldest.number)

    def _recent_command(self, text: str) -> bool:
        """Whether ``text`` is the command of one of the last lines written (an echo whose
        line number noise changed too, ``F198 G1 ...`` for line 118, names it so)."""
        history = self.writer.history
        top = self.writer.next_number - 1
        return any(history.get(n, ("",))[0] == text for n in range(top, max(0, top - 64), -1))

    def _on_start(self, now: float) -> None:
        if self.state == LinkState.CONNECTING and not self.handshaking:
            if not self.started:
                self.started = True
                self.handshake.banner(now)
        elif self.state == LinkState.RECONNECTING:
            self.state = LinkState.PAUSED if self.paused else LinkState.READY
            self.on_reset()
        else:
            self.on_reset()

    def finish_renumber(self) -> None:
        """The printer took the ``M110``: continue in the numbering it set (every record
        kept by line number is set for it here)."""
        renumber = self.writer.renumber
        assert renumber is not None
        value = renumber.value
        if renumber.token is not None:
            self.emit_acked(Acked(value, f"M110 N{value}", False, renumber.token))
        self.resync.clear()
        fresh = self.writer.end_renumber(value, renumber.keep_history)
        if fresh:
            self.resync.forget_requests()  # requests counted against the old numbers
        self.acks.renumbered(value, fresh, renumber.late_oks())
        self.model.renumbered(value)

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

    def count_resend_ok(self) -> None:
        """The ``ok`` after the ``Resend`` being read stands in for the line the refusal
        named as the last read (:attr:`PrinterModel.stands_in`): count it as that line's."""
        self._expect_resend_ok = False

    def on_lost_resend(self, error: Response) -> None:
        """An ``Error`` then its ``ok``, the ``Resend`` between them lost to noise: act on
        the request the error implies (the line after its ``Last Line``), so that a refused
        ``M110`` counts as refused and a refused line is replayed."""
        digits = str(error.line + 1) if error.line is not None else ""
        implied = Response("resend", f"Resend: {digits}",
                           line=error.line + 1 if error.line is not None else None,
                           digits=digits)
        self.resync.on_resend(implied, error, implied=True)
        self._expect_resend_ok = False  # its ok is the one being read

    def on_reset(self) -> None:
        """``start`` mid-stream: the printer rebooted and lost its buffers and line number."""
        self.stats.resets += 1
        self.resync.forget_requests()  # requests seen before the reboot confirm nothing after it
        if self.writer.renumber is None:
            value = self.acks.last_acked_number
            self.writer.begin_renumber(Renumber(value, value, keep_history=True, quiet=True))
        self.forget_in_flight()
        self.model.lost()

    def forget_in_flight(self, cut: bool = False) -> None:
        """Whatever was on the wire or in the printer's buffers is gone (a reset, or the
        port ``cut``): nothing in flight, no replay under way, an ``M110`` in progress to be
        written anew."""
        self.window.clear()
        self.resync.clear()
        self.writer.forget_in_flight()
        self.acks.forget_in_flight(cut)

    # -- connection -------------------------------------------------------------------------

    def retune(self, config: StreamerConfig) -> None:
        """New settings (firmware defaults chosen at connect): buffers apply at once."""
        self.config = config
        self.window.max_bytes = config.rx_buffer
        if config.bufsize > self.window.max_lines or not self.acks.advanced_ok:
            self.window.max_lines = max(config.bufsize, 1)
        self.window.limit = self.window.max_lines

    def begin_connect(self, now: float, *, probe_numbering: bool = False,
                      identify: bool = True) -> None:
        """The port is open: the handshake begins (:mod:`drivers.link.handshake`), waiting
        for ``start`` (the board's reset); ``Connected`` once it is done.

        ``probe_numbering``: first find out whether the printer still counts the lines of
        an earlier session (``handshake.numbering_kept``). ``identify``: ``M115`` (and
        ``M503``, ``M155``) after the ``M110``; without, the link is ready once the
        ``M110`` is answered.
        """
        self.state = LinkState.CONNECTING
        self.model.learn_keeps_buffer(False)  # a new connection: nothing learned yet
        self.model.forget_stand_in()
        self.watchdog.opened(now)
        self.handshake.begin(probe_numbering, identify)

    def begin_handshake(self, reset_to: int, keep_history: bool, token: int) -> None:
        """``M110 N<reset_to>`` once nothing is in flight; ``token`` is acknowledged when
        the printer took it."""
        self.handshaking = True  # from now on a `start` is a reset to recover from
        # numbered as the value it sets: "N1 M110 N0" set the last line to 0 on Marlin and
        # to 1 on firmware that reads the line's own number, which then refused line 1
        self.writer.begin_renumber(Renumber(reset_to, reset_to, keep_history, token=token))

    def connected(self, now: float) -> None:
        """The handshake is done: ready to stream (or paused, if paused meanwhile)."""
        self.state = LinkState.PAUSED if self.paused else LinkState.READY
        self.watchdog.polled(now)

    def link_lost(self, reason: str) -> None:
        """The port failed; the shell tries to reopen it."""
        self.state = LinkState.DISCONNECTED
        self.report(f"link lost: {reason}")

    def reopened(self, now: float) -> None:
        """The port is open again: wait for ``start`` or ``start_timeout_s``."""
        self.stats.reconnects += 1
        self.watchdog.reopened(now)
        self.forget_in_flight(cut=True)
        self.writer.queue_raw(b"\n")  # ends whatever partial line the printer kept
        self.model.lost()
        self.state = LinkState.RECONNECTING

    def start_timed_out(self, now: float) -> None:
        """No ``start`` banner within ``start_timeout_s`` of opening the port: a board that
        did not reset on open (or prints no banner) is taken as ready."""
        self.started = True
        self.handshake.banner(now)

    def reconnect_timed_out(self) -> None:
        """No ``start`` after reopening: the printer kept its state; continue after the
        last acknowledged line (it refuses, by line number, anything it already has)."""
        self.state = LinkState.PAUSED if self.paused else LinkState.READY
        first = self.acks.last_acked_number + 1
        if self.writer.renumber is None and first < self.writer.next_number:
            self.writer.replay_at(first)

    # -- the job's controls ---------------------------------------------------------------

    def emergency(self, command: str) -> list[int]:
        """``command`` (``M112``, ``M108``, ``M410``) as the very next line, past the line
        window and any replay, into the first room in the printer's receive buffer.

        ``M112`` also ends the job: the job lines not yet written are dropped (their
        tokens returned, for the shell to fail) and none is written after it; the link
        still answers the printer's resend requests, so an ``M112`` refused is sent again.
        """
        self.writer.queue_control(command, internal=False, force=True, front=True)
        if command != "M112":
            return []
        self.writer.stop_replay()
        self.stopping = True
        return self.writer.drop_pending()

    def urgent(self, command: str) -> tuple[bool, list[int]]:
        """``command`` (``M112``, ``M108``, ``M410``) at once: unnumbered, before any line,
        to a firmware with an emergency parser (``Cap:EMERGENCY_PARSER:1``), else as the
        next line (:meth:`emergency`). Returns whether it went out of band, and the tokens
        of the job lines dropped (an ``M112`` as a line), for the shell to fail.

        Out of band, Marlin acts on ``M108`` and ``M410`` at once and still queues them,
        answering ``ok`` in their place in the stream: each is in flight like the lines
        before it (uncounted, its ``ok`` acknowledged the next line before the printer had
        run it). ``M112`` kills the printer: no ``ok`` comes.
        """
        if "EMERGENCY_PARSER" not in self.capable:
            return False, self.emergency(command)
        entry = None if command == "M112" else InFlight(None, command, len(command) + 1,
                                                        internal=True)
        self.writer.queue_raw(f"{command}\n".encode(), entry)
        return True, []

    def pause(self, park: list[str]) -> None:
        """Stop job lines after those written; ``park`` lines go out first."""
        self.paused = True
        if self.state == LinkState.READY:
            self.state = LinkState.PAUSED
        for command in park:
            self.writer.queue_control(command, internal=False)

    def resume(self) -> None:
        """Job lines flow again."""
        self.paused = False
        if self.state == LinkState.PAUSED:
            self.state = LinkState.READY

    def cancel(self, end_gcode: list[str]) -> list[int]:
        """Refuse job lines; ``end_gcode`` after what is in flight. Tokens dropped."""
        self.cancelled = True
        self.paused = False
        tokens = self.writer.drop_pending()
        for command in end_gcode:
            self.writer.queue_control(command, internal=False)
        return tokens

    def cancel_done(self) -> None:
        """What the cancel sent has been written (and drained, if asked): ``CANCELLED``
        until :meth:`begin_job`, unless the link failed meanwhile."""
        if self.alive():
            self.state = LinkState.CANCELLED

    def closed(self) -> None:
        """The shell closed the port: ``DISCONNECTED``, unless the link had failed."""
        if self.alive():
            self.state = LinkState.DISCONNECTED

    def begin_job(self) -> None:
        """Accept job lines again after ``cancel``."""
        self.cancelled = False
        if self.state == LinkState.CANCELLED:
            self.state = LinkState.READY
