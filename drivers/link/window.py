"""Send-ahead window: lines written but not yet acknowledged, bounded by bytes and commands."""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field


@dataclass(slots=True)
class InFlight:
    """One line on the wire or in the printer's buffers, awaiting its ``ok``.

    ``number`` is its line number (``None`` for an unnumbered line), ``nbytes`` its framed
    length in bytes, ``internal`` marks lines the link adds itself (M110, M105, M115, M155),
    ``probe`` marks an ``M105`` whose ``ok T:...`` answer proves every earlier line done,
    ``token`` is the caller's handle for whoever waits on the line (``None``: nobody).
    """

    number: int | None
    command: str
    nbytes: int
    internal: bool = False
    probe: bool = False
    token: int | None = field(default=None, repr=False)
    copy: bool = False  # written again by a replay
    held: bool = False  # read by the printer (a refusal named it its last line), ok to come


class SendWindow:
    """FIFO of :class:`InFlight` lines; oks acknowledge them in order.

    ``max_bytes`` bounds the bytes not yet acknowledged (the firmware's receive buffer,
    127 for Marlin's 128-byte ring); ``max_lines`` bounds the commands (``BUFSIZE``).
    Within those the window adapts to the noise on the line: ``limit`` (lines) halves on
    every refusal and grows back by one line for every ``limit`` clean acknowledgements,
    so a noisy wire degrades towards one line in flight (a send-and-wait host) instead of
    feeding refusals with lines that will be refused too.
    """

    def __init__(self, max_bytes: int, max_lines: int) -> None:
        self.max_bytes = max_bytes
        self.max_lines = max_lines
        self.limit = max_lines
        self._credit = 0
        self._entries: deque[InFlight] = deque()
        self._bytes = 0
        self._held = 0  # entries the printer has read, whose ok may never come

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[InFlight]:
        return iter(self._entries)

    @property
    def held(self) -> int:
        """Lines in flight the printer has read (:meth:`release`), their oks uncertain."""
        return self._held

    @property
    def bytes_in_flight(self) -> int:
        """Framed bytes written and not yet acknowledged."""
        return self._bytes

    def has_room(self, nbytes: int) -> bool:
        """True if a line of ``nbytes`` may be written now (always, when nothing is in flight)."""
        entries = self._entries
        if not entries:
            return True
        limit = self.limit if self.limit < self.max_lines else self.max_lines
        return self._bytes + nbytes <= self.max_bytes and len(entries) - self._held < limit

    def full_for(self, nbytes: int) -> bool:
        """True if a line of ``nbytes`` must wait (the opposite of :meth:`has_room`)."""
        entries = self._entries
        if not entries:
            return False
        limit = self.limit if self.limit < self.max_lines else self.max_lines
        return self._bytes + nbytes > self.max_bytes or len(entries) - self._held >= limit

    def shrink(self) -> None:
        """A refusal: halve the line limit (at least one line stays allowed)."""
        self.limit = max(1, min(self.limit, self.max_lines) // 2)
        self._credit = 0

    def grow(self) -> None:
        """A clean acknowledgement: after ``limit`` of them, one more line is allowed."""
        if self.limit >= self.max_lines:
            self.limit = self.max_lines
            return
        self._credit += 1
        if self._credit >= self.limit:
            self._credit = 0
            self.limit += 1

    def push(self, entry: InFlight) -> None:
        """Record a line just written."""
        self._entries.append(entry)
        self._bytes += entry.nbytes

    def oldest(self) -> InFlight | None:
        """The line written first of those in flight (None: nothing in flight)."""
        return self._entries[0] if self._entries else None

    def ack_one(self) -> list[InFlight]:
        """A plain ``ok``: the oldest line is done."""
        if not self._entries:
            return []
        return [self._pop()]

    def ack_through(self, number: int) -> list[InFlight]:
        """An advanced ``ok N<number>``: every line up to ``number`` is done."""
        done: list[InFlight] = []
        if not any(e.number == number for e in self._entries):
            return done
        while self._entries:
            entry = self._pop()
            done.append(entry)
            if entry.number == number:
                break
        return done

    def ack_upto(self, number: int) -> list[InFlight]:
        """The printer took every line up to ``number``: their entries are done, copies of
        them written later too (the printer refuses or drains those: no ``ok`` of theirs
        comes); lines of higher numbers stay, in order."""
        entries = self._entries
        if entries and entries[0].number == number:
            for later in itertools.islice(entries, 1, None):
                if later.number is None or later.number <= number:
                    break  # a copy of a line done, or an unnumbered line: the general case
            else:
                entry = entries.popleft()  # the usual case: the oldest line, nothing else
                self._bytes -= entry.nbytes
                if entry.held:
                    self._held -= 1
                return [entry]
        # an unnumbered line (written out of band) is done once a line after it is
        last = max((k for k, e in enumerate(entries)
                    if e.number is not None and e.number <= number), default=-1)
        done: list[InFlight] = []
        kept: deque[InFlight] = deque()
        for k, e in enumerate(entries):
            finished = k < last if e.number is None else e.number <= number
            (done if finished else kept).append(e)
        if done:
            self._entries = kept
            self._bytes -= sum(e.nbytes for e in done)
            self._held -= sum(e.held for e in done)
        return done

    def ack_probe(self) -> list[InFlight]:
        """An ``ok T:...`` (the answer to an ``M105``): that line and every line before it
        are done.

        The printer answers in order, so the answer is the oldest ``M105`` still held's
        (a probe, or a job's own); probes right behind it go too (their answers, still to
        come, then match nothing), so a window of unanswered-looking probes resyncs at
        once. An older probe whose answer was lost has been shifted out by the plain oks
        since. An answer that matches no ``M105`` in flight belongs to a probe already
        counted and acknowledges nothing: it never takes a job line.
        """
        entries = list(self._entries)
        first = next((k for k, e in enumerate(entries) if _is_m105(e.command)), None)
        if first is None:
            return []
        last = first
        while last + 1 < len(entries) and entries[last + 1].internal \
                and _is_m105(entries[last + 1].command):
            last += 1
        return [self._pop() for _ in range(last + 1)]

    def drop_from(self, number: int) -> list[InFlight]:
        """Forget lines numbered ``number`` and later (the printer discarded them)."""
        kept: deque[InFlight] = deque()
        dropped: list[InFlight] = []
        for entry in self._entries:
            if entry.number is not None and entry.number >= number:
                dropped.append(entry)
            else:
                kept.append(entry)
        self._entries = kept
        self._bytes = sum(e.nbytes for e in kept)
        self._held = sum(e.held for e in kept)
        return dropped

    def drop_copy(self, last_line: int) -> InFlight | None:
        """Forget the oldest replayed copy of a line up to ``last_line`` (the printer held
        the line already and refused the copy: it will get no ``ok``)."""
        for entry in self._entries:
            if entry.copy and entry.number is not None and entry.number <= last_line:
                self._entries.remove(entry)
                self._bytes -= entry.nbytes
                self._held -= entry.held
                return entry
        return None

    def release(self, last_line: int) -> list[InFlight]:
        """The printer has read line ``last_line`` (a refusal named it as its last line):
        it leaves its receive buffer and stops counting against the window, though its ok
        may still come (some firmware sends none for a line whose refusal of the next
        stood in for it; the lines before it get theirs either way). Returns it, if it
        was in flight and not released before."""
        for entry in self._entries:
            if entry.number == last_line and not entry.held:
                entry.held = True
                self._bytes -= entry.nbytes
                entry.nbytes = 0
                self._held += 1
                return [entry]
        return []

    def clear(self) -> list[InFlight]:
        """Forget every line (the printer reset or the link was lost)."""
        dropped = list(self._entries)
        self._entries.clear()
        self._bytes = 0
        self._held = 0
        return dropped

    def numbers(self) -> list[int]:
        """Line numbers in flight, oldest first."""
        return [e.number for e in self._entries if e.number is not None]

    def _pop(self) -> InFlight:
        entry = self._entries.popleft()
        self._bytes -= entry.nbytes
        if entry.held:
            self._held -= 1
        return entry


def _is_m105(command: str) -> bool:
    return command.split(" ", 1)[0] == "M105"
