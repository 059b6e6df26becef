"""The protocol core's acknowledgement counter: which lines an ``ok`` completes, reported once.

:class:`AckCounter` owns the count (the last line acknowledged, the job lines acknowledged,
the acknowledgements reported), what makes an ``ok`` uncertain (oks lost to a cut port,
late oks of an ``M110`` written again, answers owed to probes, a refusal's probe awaited)
and the waiters of the link's own lines. The core (:class:`~drivers.link.core.LinkCore`)
holds it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.link.events import Acked
from drivers.link.responses import Response
from drivers.link.window import InFlight

if TYPE_CHECKING:  # the core holds the counter; the counter asks it (one-way at run time)
    from drivers.link.core import LinkCore

# most oks awaited for an M110 written several times
MAX_LATE_OKS = 8


def _is_probe_line(held: tuple[str, bool] | None, internal: bool = False) -> bool:
    """True for a history entry that is an ``M105`` (the link's own, with ``internal``)."""
    return held is not None and held[0].split(" ", 1)[0] == "M105" \
        and (held[1] or not internal)


class AckCounter:
    """Oks counted, lines acknowledged (see the module docstring)."""

    def __init__(self, core: LinkCore) -> None:
        """Nothing acknowledged yet."""
        self.core = core
        self.window = core.window
        self.model = core.model
        self.acked = 0  # job lines acknowledged
        self.last_acked_number = 0
        self.emitted_through = 0  # the last line whose acknowledgement was reported
        self.advanced_ok = False  # the firmware sends ``ok ... B<n>``
        self.oks_lost = False  # the port was cut: oks are counted in the window's order
        self.late_oks = 0  # oks of M110s written again, still to come and not counted
        self.answers_owed: list[int] = []  # probes acknowledged ahead of their answers
        self.resolving = False  # a probe after a refusal is out: no job line until answered
        self.doubt = False  # an answer taken for an owed one may have been a probe's in flight
        # refusals that released a line, awaiting the probe asked after them: its answer
        # shows whether the ok after each Resend stood in for the released line's own
        self.stand_in_checks = 0
        self.waiters: dict[int, int] = {}  # line number -> token of a replayed control line

    def on_ok(self, response: Response) -> None:
        """One ``ok`` (plain, advanced, or a probe's ``ok T:``), in the order received."""
        probe_answer = bool(response.temperatures)
        checks = 0
        if probe_answer and self.stand_in_checks:
            checks, self.stand_in_checks = self.stand_in_checks, 0
        if probe_answer and self.resolving and not self.answers_owed:
            newest = self._past_held_probe()
            if newest is not None:
                # the probe asked after a refusal that left an older probe's answer
                # uncertain: this answer is taken for it, every line before it done. Had
                # the older probes' answers come after all (this one among them), as many
                # are still to come: owed, each acknowledges nothing. Every older probe
                # counts, not only the held ones: one not held (answered for certain) is
                # most likely the one this answer is for. Owing one answer too few took
                # a late answer for a newer probe behind job lines, acknowledging them
                # before they ran (a reset then renumbered past them); one too many is
                # cleared by the next plain ok, or costs a probe after a short silence.
                # Older probes no longer in the window count too (every line from the
                # count to this probe is one): a refusal naming one as the last line read
                # takes it out of the window, and its answer may still come (the seeded
                # loop's silent_duplicates seed 81: three answers for three probes, two
                # counted, the third taken for a probe behind job lines)
                self.resolving = False
                self.late_oks = 0
                self.answers_owed = [newest] * (newest - self.last_acked_number - 1)
                done = self.window.ack_upto(newest)
                if not any(e.number == newest for e in done):
                    return
                for entry in done:
                    self.acknowledged(entry)
                return
        if probe_answer:
            self.late_oks = 0  # a probe's answer: any late ok came before it
            if self.answers_owed:
                # the answer of a probe acknowledged with the one before it: the printer
                # has answered up to that probe now, and no line after it
                del self.answers_owed[0]
                # taken for the owed answer, it may have been the probe's in flight (the
                # older answer was withheld): if nothing follows, ask again soon
                self.doubt = any(e.probe for e in self.window)
                return
        elif self.answers_owed:
            self.answers_owed = []  # answers come in order: those owed came (or were lost)
        if not probe_answer and self.late_oks:
            self.late_oks -= 1
            return
        if response.queue_free is not None:
            self.advanced_ok = True
            if self.core.config.learn_bufsize and response.queue_free + 1 > self.window.max_lines:
                grown = self.window.limit >= self.window.max_lines
                self.window.max_lines = response.queue_free + 1
                if grown:
                    self.window.limit = self.window.max_lines
        # oks are counted in order; an advanced ok's N is not trusted to name the line it
        # acknowledges (firmwares print the last line received or the one executed)
        if self.core.writer.renumber is not None:
            # the M110 numbers itself apart (a reset's M110 reuses the last line's number)
            done = self._ack_probe() if probe_answer else self.window.ack_one()
        else:
            done = self._ack_by_count(probe_answer)
        if not done:
            return
        if checks:
            self._check_stand_in(done, checks)
        self.doubt = False
        last = self.core.writer.next_number - 1
        for entry in done:
            if entry.probe and entry.number == last:
                self.core.writer.fence()  # (a firmware that answers M105 without temperatures too)
        if self.core.writer.replay_next is None:
            self.window.grow()
        for entry in done:
            self.acknowledged(entry)

    def _check_stand_in(self, done: list[InFlight], released: int) -> None:
        """A probe's answer after ``released`` refusals that each released a line: the
        lines it acknowledges before it got no ok of their own. As many as the refusals:
        each Resend's ok (not counted) stood in for the released line's; none: each of
        those lines had its own. Anything else (an ok lost, a late one) tells nothing."""
        unanswered = sum(1 for e in done if not _is_probe_line((e.command, e.internal)))
        if unanswered == released:
            self.model.saw_stand_in(True)
        elif unanswered == 0:
            self.model.saw_stand_in(False)

    def _past_held_probe(self) -> int | None:
        """The first probe in flight that the printer has not been seen to read, when
        every line from the count up to it is an ``M105`` and one of them is a probe a
        refusal named as the printer's last line; else ``None`` (the count decides).

        Such a probe may never be answered (the firmware's ok after the ``Resend`` stood
        for it): counted for it, the answer of the probe asked next left the count a line
        behind for good, and the window waited. With nothing but probes between, taking
        the answer for the newer probe acknowledges no job line early."""
        held = [e.number for e in self.window if e.held and e.number is not None
                and _is_probe_line((e.command, True))]
        if not held:
            return None
        later = next((e.number for e in self.window if e.probe and not e.held
                      and e.number is not None and e.number > held[0]), None)
        if later is None:
            return None
        history = self.core.writer.history
        if any(not _is_probe_line(history.get(n)) for n in
               range(self.last_acked_number + 1, later)):
            return None
        return later

    def _ack_probe(self) -> list[InFlight]:
        """An ``ok T:`` in the window's order: the oldest ``M105`` in flight, with the
        probes right behind it, whose own answers are then owed (see ``_ack_by_count``)."""
        done = self.window.ack_probe()
        first = next((k for k, e in enumerate(done) if _is_probe_line((e.command, True))),
                     None)
        if first is not None:
            self.answers_owed = [e.number for e in done[first + 1:] if e.number is not None]
        return done

    def _ack_by_count(self, probe_answer: bool) -> list[InFlight]:
        """A plain ``ok`` is the line's after the last one acknowledged; an ``ok T:`` the
        first ``M105`` from there, with the probes right behind it.

        The probes right behind it are done as far as the job goes (nothing but probes
        since: a pile of probes whose answers were lost resyncs at once), but the printer
        has not answered them yet: their answers are owed (``_answers_owed``) and come
        before any other, each acknowledging nothing. Counted for lines after them, each
        would put the count one line ahead of what the printer answered, and a reset
        would then renumber past lines never run.

        Marlin takes numbered lines strictly in sequence and answers each with one ok, so
        the oks name consecutive lines whatever copies were written. A line dropped from
        the window as refused may have been taken after all (the refusal that started a
        replay was spurious, or a refusal was taken for a copy's): its ok is still its
        own, never a later line's. Copies of lines done are dropped from the window (the
        printer refuses or drains them: no ok of theirs comes). When the count is off (an
        ok lost or an extra one read) the window's order decides, as before; a probe's
        answer sets the count right.
        """
        history = self.core.writer.history
        oldest = self.window.oldest()
        if oldest is not None and oldest.number is None and not probe_answer:
            return self.window.ack_one()  # a line written out of band, every one before done
        number = self.last_acked_number + 1
        if self.oks_lost:
            # the port was cut: oks of lines run meanwhile are lost, so the count is behind
            # by an unknown number; the window's order decides (refusals naming the last
            # line held drop the copies of those lines) until it meets the count again
            done = self._ack_probe() if probe_answer else self.window.ack_one()
            if any(e.number is not None and e.number >= number for e in done):
                self.oks_lost = False
            return done
        if probe_answer:
            while number < self.core.writer.next_number and not _is_probe_line(history.get(number)):
                number += 1
            if number >= self.core.writer.next_number:
                return self._ack_probe()
            ahead: list[int] = []
            while number + 1 < self.core.writer.next_number \
                    and _is_probe_line(history.get(number + 1), internal=True):
                number += 1
                ahead.append(number)
            self.answers_owed = ahead
        held = history.get(number)
        if held is None or number >= self.core.writer.next_number:
            return self._ack_probe() if probe_answer else self.window.ack_one()
        done = self.window.ack_upto(number)
        if len(done) == 1 and done[0].number == number:
            return done  # the usual case: the oldest line in flight, alone
        if not any(e.number == number for e in done):
            command, internal = held
            done.append(InFlight(number, command, 0, internal=internal,
                                 probe=internal and _is_probe_line(held)))
        return done

    def acknowledged(self, entry: InFlight) -> None:
        """Record one line as done, in the numbering it was written under.

        An ``M110`` that completes a renumbering is recorded like any line, in the old
        numbering, and only then starts the new one, so that the records kept by line number
        (``last_acked_number``, ``_emitted_through``) end as the new numbering sets them.
        """
        number = entry.number
        repeated = number is not None and number <= self.emitted_through
        if number is not None and not repeated and number > self.emitted_through + 1:
            self._catch_up(number)
        if number is not None:
            if number > self.last_acked_number:
                self.last_acked_number = number
            if number > self.model.held:
                self.model.held = number  # (PrinterModel.holds, inline: once per line)
            if not repeated:
                self.emitted_through = number
        token = entry.token
        if number is not None:
            # a line replayed after a refusal or reset is a new entry: its waiter is by number
            token = self.waiters.pop(number, token)
        job = not entry.internal and not repeated  # not again when replayed after a refusal
        if job:
            self.acked += 1
        if job or token is not None:
            self.core.emit_acked(Acked(number if number is not None else -1, entry.command,
                                       job, token))
        if self.core.writer.completes_renumber(entry):
            self.core.finish_renumber()

    def _catch_up(self, number: int) -> None:
        """Line ``number`` is done, so is every line before it (the printer runs them in
        order): acknowledge those not yet acknowledged (their own oks were counted for
        copies written again, or for lines the printer refused)."""
        for earlier in range(self.emitted_through + 1, number):
            held = self.core.writer.history.get(earlier)
            if held is None:
                continue
            command, internal = held
            token = self.waiters.pop(earlier, None)
            if not internal:
                self.acked += 1
            if not internal or token is not None:
                self.core.emit_acked(Acked(earlier, command, not internal, token))
        self.emitted_through = max(self.emitted_through, number - 1)

    def remember_waiter(self, number: int, token: int) -> None:
        """A control line's waiter, found again by number when the line is replayed."""
        self.waiters[number] = token

    def resolve_by_probe(self) -> None:
        """A probe asked after a refusal: no job line until it is answered."""
        self.resolving = True

    def resolved(self) -> None:
        """The refusal's probe was answered (or taken back)."""
        self.resolving = False

    def suspect(self, doubt: bool) -> None:
        """Whether an answer just taken may have been another's (probe soon if silent)."""
        self.doubt = doubt

    def forget_owed(self) -> None:
        """Answers owed to probes will not come (withheld through a long silence)."""
        self.answers_owed = []

    def take_back(self, number: int) -> None:
        """The printer holds every line before ``number`` and none from it: the
        acknowledgements counted past it were for lines it refused."""
        self.last_acked_number = number - 1
        self.drop_owed_from(number)

    def drop_owed_from(self, number: int) -> None:
        """Probes from ``number`` on are written again: their copies' answers are counted."""
        self.answers_owed = [n for n in self.answers_owed if n < number]

    def renumbered(self, value: int, fresh: bool, late_oks: int) -> None:
        """An ``M110`` set the last line to ``value``; ``fresh``: numbering restarts (no
        line kept to replay); ``late_oks``: oks of earlier writes of it still to come."""
        if fresh:
            self.emitted_through = value
        self.last_acked_number = value
        self.oks_lost = False  # the count restarts from the M110
        # an M110 written again after silence may have its first ok still to come, before
        # any ok of the lines that follow: those oks are not counted for them
        self.late_oks = min(late_oks, MAX_LATE_OKS)

    def forget_in_flight(self, cut: bool) -> None:
        """What was in flight is gone (a reset, or the port ``cut``: then the oks of lines
        run meanwhile are lost and the count follows the window's order)."""
        self.resolving = False
        self.doubt = False
        self.late_oks = 0
        self.answers_owed = []
        self.stand_in_checks = 0
        if cut:
            self.oks_lost = True

    def forget_waiters(self) -> None:
        """The link failed: nobody waits for a replayed line any more."""
        self.waiters.clear()
