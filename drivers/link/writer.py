"""The protocol core's writer: which line goes out next, if the window allows one.

:class:`LinkWriter` owns what is queued (job lines, the link's own lines), the line
numbering (the next number, the lines kept for resends, an ``M110`` in progress) and the
replay after a refusal. The core (:class:`~drivers.link.core.LinkCore`) holds it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

from drivers.link.events import STOPPED, Written
from drivers.link.protocol import frame
from drivers.link.window import InFlight

if TYPE_CHECKING:  # the core holds the writer; the writer asks it (one-way at run time)
    from drivers.link.core import LinkCore


@dataclass
class Renumber:
    """An ``M110`` in progress: sets the last line to ``value``, and is written as line
    ``value`` itself (``N0 M110 N0``), the one form every firmware reads alike: Marlin takes
    the parameter, some firmware (and OctoPrint's virtual printer) the line's own number.
    ``line`` is the number the core records it under (the same)."""

    line: int
    value: int
    keep_history: bool
    token: int | None = None
    sent: bool = False
    sent_at: float = 0.0
    quiet: bool = False
    writes: int = 0  # times the M110 was written
    refusals: int = 0  # resend requests while it was out (each may stand for a write)

    def late_oks(self) -> int:
        """Oks still to come for the writes the completing ok did not answer: every write
        is answered once, by an ok or by a refusal (counted generously, so that a line of
        the new numbering is never taken for one)."""
        return max(0, self.writes - 1 - self.refusals)


@dataclass
class Control:
    """A line the link (``internal``) or the user adds outside the job: ``force`` passes
    the window, ``probe`` marks an ``M105`` asked to find lost oks."""

    command: str
    internal: bool
    probe: bool = False
    force: bool = False
    token: int | None = None


class LinkWriter:
    """The writer's decisions and the fields they rest on (see the module docstring)."""

    def __init__(self, core: LinkCore) -> None:
        """Nothing queued, numbering from 1."""
        self.core = core
        self.window = core.window
        self.model = core.model
        self.stats = core.stats
        self.pending: deque[tuple[str, int]] = deque()  # job lines: command, token
        self.control: deque[Control] = deque()  # the link's or the user's own lines
        self.next_number = 1
        self.history: dict[int, tuple[str, bool]] = {}  # number -> (command, internal)
        self.renumber: Renumber | None = None  # an M110 in progress
        self.replay_next: int | None = None  # the next line a replay writes again
        self.force_replay = False  # a probe is due: one replayed line passes the window
        self.fenced = False  # a probe written after every other line has been answered
        self._framed: tuple[int, str, bytes] | None = None  # the next job line, framed
        # bytes written as they are, before any line (unnumbered, outside the protocol:
        # the newline and the numbering probe of the handshake, a line to an emergency
        # parser), each with its entry in the window if the printer answers it
        self.raw: deque[tuple[bytes, InFlight | None]] = deque()

    def queue_job(self, command: str, token: int) -> None:
        """A job command to write after those already queued; ``Written`` tells its number."""
        self.pending.append((command, token))

    def queue_control(self, command: str, *, internal: bool, token: int | None = None,
                      probe: bool = False, force: bool = False, front: bool = False) -> None:
        """A line outside the job; ``front`` puts it before everything queued."""
        control = Control(command, internal, probe=probe, force=force, token=token)
        if front:
            self.control.appendleft(control)
        else:
            self.control.append(control)

    def drop_pending(self) -> list[int]:
        """Forget the job lines not yet written; their tokens, for the shell to fail."""
        tokens = [token for _, token in self.pending]
        self.pending.clear()
        return tokens

    def queue_raw(self, data: bytes, entry: InFlight | None = None) -> None:
        """``data`` to write before any line, whatever the link's state; ``entry`` goes in
        the window when it is written (a line the printer answers in the stream's order)."""
        self.raw.append((data, entry))

    def next_bytes(self, now: float) -> bytes | None:
        """The next bytes to write now (recorded as written), or ``None``."""
        if self.raw:
            data, raw_entry = self.raw.popleft()
            if raw_entry is not None:
                self.window.push(raw_entry)
            return data
        if self.core.state in STOPPED:
            return None
        out = self._next_line(now)
        if out is None:
            return None
        data, entry = out
        if entry is not None:
            self.window.push(entry)
        self.stats.lines_sent += 1
        self.stats.bytes_sent += len(data)
        return data

    def _next_line(self, now: float) -> tuple[bytes, InFlight | None] | None:
        if self.renumber is not None:
            return self._next_renumber_line(now)
        if self.replay_next is not None:
            return self._next_replay_line(now)
        if self.control:
            return self._next_control_line(now)
        if self.core.acks.resolving and not any(c.probe for c in self.control) \
                and not any(e.probe for e in self.window):
            self.core.acks.resolved()  # the probe was answered (or taken back) meanwhile
        core = self.core
        if self.pending and not core.paused and not core.cancelled and not core.stopping \
                and not core.acks.resolving:
            number = self.next_number
            if number >= self.core.config.renumber_at:
                if len(self.window):
                    # drain first, outside the renumbering: until the M110 is written the
                    # printer keeps the old numbers, and a probe must recover a lost ok
                    return None
                if not self.fenced:
                    # the ok count may be off (noise): only a probe's answer after the last
                    # line proves every line taken, and lines refused after the M110 could
                    # never be replayed
                    if not any(c.probe for c in self.control):
                        self.queue_control("M105", internal=True, probe=True)
                    return self._next_control_line(now)
                self.stats.renumbers += 1
                self.renumber = Renumber(0, 0, keep_history=False)
                return self._next_renumber_line(now)
            command, token = self.pending[0]
            framed = self._framed
            if framed is not None and framed[0] == number and framed[1] is command:
                data = framed[2]
            else:
                data = frame(number, command)
                self._framed = (number, command, data)
            if self.window.full_for(len(data)):
                return None  # framed once: the line waits for room as it is
            self.pending.popleft()
            # the line's number assigned (as ``_assign`` does, inline: once per job line)
            self.fenced = False
            self.next_number = number + 1
            history = self.history
            history[number] = (command, False)
            history.pop(number - self.core.config.history, None)
            self.core.emit(Written(token, number))
            return data, InFlight(number, command, len(data))
        return None

    def _next_renumber_line(self, now: float) -> tuple[bytes, InFlight | None] | None:
        """``M110`` once nothing else is in flight; only forced lines pass it."""
        renumber = self.renumber
        assert renumber is not None
        if self.control and self.control[0].force and not self.control[0].probe:
            return self._next_control_line(now)
        if renumber.sent or len(self.window):
            return None
        if renumber.quiet and now - self.core.watchdog.last_rx < self.core.config.resync_quiet_s:
            return None  # let replies to lines sent before the reset arrive first
        command = f"M110 N{renumber.value}"
        data = frame(renumber.line, command)
        renumber.sent = True
        renumber.writes += 1
        renumber.sent_at = now
        return data, InFlight(renumber.line, command, len(data), internal=True)

    def _next_replay_line(self, now: float) -> tuple[bytes, InFlight | None] | None:
        number = self.replay_next
        assert number is not None
        if self.control and self.control[0].force and not self.control[0].probe:
            return self._next_control_line(now)
        held = self.history.get(number)
        if held is None:
            self.core.fail(f"printer asked for line {number}, which is no longer held")
            return None
        command, internal = held
        data = frame(number, command)
        if not self.window.has_room(len(data)):
            if not self.force_replay:
                return None
            if not self.core.watchdog.may_force(len(data), now):
                return None  # not into a full receive buffer (or later: see may_force)
            # a probe is due and the window looks full (an ok lost: the count stays a line
            # behind; or the printer is slow, and its receive buffer is full): one line
            # passes it, as the probe itself would, and each later probe due lets one
            # more. Letting the whole replay pass at once wrote hundreds of lines (the
            # probes of a long silence, each numbered) into a 128-byte buffer; the
            # overflow was refused, replayed and overflowed again, for ever
            # (bench/stall_hunt.py, docs/streaming.md)
            self.force_replay = False
        self.replay_next = number + 1 if number + 1 < self.next_number else None
        if self.replay_next is None:
            self.force_replay = False
        self.stats.lines_resent += 1
        self.model.copy(number)
        return data, InFlight(number, command, len(data), internal=internal,
                              probe=command == "M105" and internal, copy=True)

    def _next_control_line(self, now: float) -> tuple[bytes, InFlight | None] | None:
        control = self.control[0]
        data = frame(self.next_number, control.command)
        if not self.window.has_room(len(data)):
            if not control.force:
                return None
            if not self.core.watchdog.may_force(len(data), now):
                # into a receive buffer the model says full only as the silence doubles: an
                # overrun merged a probe with the next line (checksum still matching), and
                # cut an M112 short, to be asked for again only if more lines came
                return None
        self.control.popleft()
        number = self._assign(control.command, internal=control.internal)
        if control.token is not None:
            self.core.acks.remember_waiter(number, control.token)
        return data, InFlight(number, control.command, len(data), internal=control.internal,
                              probe=control.probe, token=control.token)

    def _assign(self, command: str, internal: bool = False) -> int:
        self.fenced = False
        number = self.next_number
        self.next_number += 1
        self.history[number] = (command, internal)
        self.history.pop(number - self.core.config.history, None)
        return number

    # -- what the other parts of the core ask of the writer --------------------------------

    def drop_all(self) -> None:
        """Forget every queued line (the link failed)."""
        self.pending.clear()
        self.control.clear()

    def begin_renumber(self, renumber: Renumber) -> None:
        """An ``M110`` to write once nothing else is in flight."""
        self.renumber = renumber

    def completes_renumber(self, entry: InFlight) -> bool:
        """Whether ``entry``, acknowledged, is the ``M110`` in progress."""
        renumber = self.renumber
        return (renumber is not None and renumber.sent and entry.number == renumber.line
                and entry.command.startswith("M110"))

    def end_renumber(self, value: int, keep_history: bool) -> bool:
        """The printer took the ``M110`` setting its last line to ``value``: replay the
        lines kept after it (``keep_history``), or number afresh from ``value + 1`` (then
        True: the numbering restarts)."""
        self.renumber = None
        if keep_history and value + 1 < self.next_number:
            self.replay_next = value + 1
            return False
        self.history.clear()
        self.next_number = value + 1
        self.replay_next = None
        self.force_replay = False
        return True

    def write_renumber_again(self) -> None:
        """The ``M110`` went unanswered: it is idempotent, write it again."""
        assert self.renumber is not None
        self.window.clear()
        self.renumber.sent = False

    def forget_in_flight(self) -> None:
        """What was in flight is gone: no replay, an ``M110`` in progress written anew."""
        self.stop_replay()
        renumber = self.renumber
        if renumber is not None:
            renumber.sent = False
            renumber.writes = renumber.refusals = 0

    def replay_at(self, number: int) -> None:
        """Write the lines from ``number`` again, after those in flight."""
        self.replay_next = number

    def skip_replay_to(self, number: int) -> None:
        """The printer holds every line before ``number``: a replay under way skips them."""
        if self.replay_next is not None and self.replay_next < number:
            self.replay_next = number if number < self.next_number else None
            if self.replay_next is None:
                self.force_replay = False

    def stop_replay(self) -> None:
        """No replay under way (what was in flight is gone, or an ``M112`` goes first)."""
        self.replay_next = None
        self.force_replay = False

    def urge_probe(self) -> None:
        """A probe is due: the replay's next line may pass the window (as the probe would),
        and the probe goes out past it, ahead of the lines waiting for room (see
        :meth:`~drivers.link.watchdog.Watchdog.probe`)."""
        if self.replay_next is not None:
            self.force_replay = True
        queued = next((c for c in self.control if c.probe), None)
        if queued is None:
            queued = Control("M105", internal=True, probe=True, force=True)
        else:
            queued.force = True
            self.control.remove(queued)
        # ahead of the lines waiting for room in the window (park or end G-code, a user's
        # command): when the count holds room the printer has freed (oks lost), only a
        # probe's answer frees it, and a probe behind them was never written (the link
        # then declared a printer that answered every line dead)
        at = next((k for k, c in enumerate(self.control) if not c.force), len(self.control))
        self.control.insert(at, queued)

    def fence(self) -> None:
        """A probe written after every other line was answered: every line is taken."""
        self.fenced = True
