"""The protocol core's writing half: which line goes out next, if the window allows one."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.linkevents import STOPPED, LinkState, Written
from drivers.linkfields import CoreFields
from drivers.protocol import frame
from drivers.window import InFlight


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


class Writing(CoreFields):
    """Mixin of :class:`~drivers.linkcore.LinkCore`: the writer's decisions."""

    force_replay = False  # a probe is due: one replayed line passes the window
    fenced = False  # a probe written after every other line has been answered
    _framed: tuple[int, str, bytes] | None = None  # the next job line, framed

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

    def next_bytes(self, now: float) -> bytes | None:
        """The next line to write now (recorded as written), or ``None``."""
        if self.state in STOPPED:
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
        if self.resolving and not any(c.probe for c in self.control) \
                and not any(e.probe for e in self.window):
            self.resolving = False  # the probe was answered (or taken back) meanwhile
        if self.pending and not self.paused and not self.cancelled and not self.stopping \
                and not self.resolving:
            number = self.next_number
            if number >= self.config.renumber_at:
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
            history.pop(number - self.config.history, None)
            self._events.append(Written(token, number))
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
        if renumber.quiet and now - self.last_rx < self.config.resync_quiet_s:
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
            self.fail(f"printer asked for line {number}, which is no longer held")
            return None
        command, internal = held
        data = frame(number, command)
        if not self.window.has_room(len(data)):
            if not self.force_replay:
                return None
            if not self.may_force(len(data), now):
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
            if not self.may_force(len(data), now):
                # into a receive buffer the model says full only as the silence doubles: an
                # overrun merged a probe with the next line (checksum still matching), and
                # cut an M112 short, to be asked for again only if more lines came
                return None
        self.control.popleft()
        number = self._assign(control.command, internal=control.internal)
        if control.token is not None:
            self.remember_waiter(number, control.token)
        return data, InFlight(number, control.command, len(data), internal=control.internal,
                              probe=control.probe, token=control.token)

    def _assign(self, command: str, internal: bool = False) -> int:
        self.fenced = False
        number = self.next_number
        self.next_number += 1
        self.history[number] = (command, internal)
        self.history.pop(number - self.config.history, None)
        return number

    def emergency(self, command: str) -> list[int]:
        """``command`` (``M112``, ``M108``, ``M410``) as the very next line, past the line
        window and any replay, into the first room in the printer's receive buffer.

        ``M112`` also ends the job: the job lines not yet written are dropped (their
        tokens returned, for the shell to fail) and none is written after it; the link
        still answers the printer's resend requests, so an ``M112`` refused is sent again.
        """
        self.queue_control(command, internal=False, force=True, front=True)
        if command != "M112":
            return []
        self.replay_next = None
        self.force_replay = False
        self.stopping = True
        return self.drop_pending()

    def out_of_band(self, command: str) -> None:
        """``command`` was written unnumbered, straight after the lines already written
        (``M108`` or ``M410`` to an emergency parser). Marlin acts on it at once and still
        queues it, answering ``ok`` in its place in the stream: it is in flight like the
        lines before it. Uncounted, its ``ok`` acknowledged the next line before the
        printer had run it."""
        self.window.push(InFlight(None, command, len(command) + 1, internal=True))

    def pause(self, park: list[str]) -> None:
        """Stop job lines after those written; ``park`` lines go out first."""
        self.paused = True
        if self.state == LinkState.READY:
            self.state = LinkState.PAUSED
        for command in park:
            self.queue_control(command, internal=False)

    def resume(self) -> None:
        """Job lines flow again."""
        self.paused = False
        if self.state == LinkState.PAUSED:
            self.state = LinkState.READY

    def cancel(self, end_gcode: list[str]) -> list[int]:
        """Refuse job lines; ``end_gcode`` after what is in flight. Tokens dropped."""
        self.cancelled = True
        self.paused = False
        tokens = self.drop_pending()
        for command in end_gcode:
            self.queue_control(command, internal=False)
        return tokens

    def begin_job(self) -> None:
        """Accept job lines again after ``cancel``."""
        self.cancelled = False
        if self.state == LinkState.CANCELLED:
            self.state = LinkState.READY
