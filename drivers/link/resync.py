"""The protocol core's answer to refusals: which line to replay from, once per refusal.

:class:`Resync` owns what it counts of the requests themselves (a request not announced
by an ``Error``, one for an implausible line, awaiting confirmation by repetition); the
model of the printer's line bookkeeping it reasons on (:mod:`drivers.link.model`) is the
core's, shared with the writer and the counter. The core
(:class:`~drivers.link.core.LinkCore`) holds it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers.link.resend import resolve_resend
from drivers.link.responses import Response

if TYPE_CHECKING:  # the core holds the resync; the resync asks it (one-way at run time)
    from drivers.link.core import LinkCore


class Resync:
    """Resend requests and refusals (see the module docstring)."""

    def __init__(self, core: LinkCore) -> None:
        """No request seen yet."""
        self.core = core
        self.window = core.window
        self.model = core.model
        self.stats = core.stats
        self._unconfirmed: tuple[int, int] = (-1, 0)
        self._implausible: tuple[str, int] = ("", 0)

    def clear(self) -> None:
        """No replay under way and no refusal expected (reset, renumbering, link cut)."""
        self.model.settled()

    def forget_requests(self) -> None:
        """Requests counted so far name other lines now (new numbering, or a reboot)."""
        self._unconfirmed = (-1, 0)
        self._implausible = ("", 0)

    def on_resend(self, response: Response, error_before: Response | None,
                  implied: bool = False) -> None:
        """``Resend: N``: replay from N, when the request is sane.

        The number is checked against the lines that can be asked for (unacknowledged or
        next), repaired when digits were lost, confirmed by the ``Error`` line before it or
        by repetition; further requests for the same error (lines that were still on the
        wire) are answered once; a request for an acknowledged line means lost state.
        """
        error_line = error_before.line if error_before is not None else None
        self.stats.resends += 1
        if self.core.writer.renumber is not None:
            self._refused_during_renumber(error_before)
            return
        # a probe acknowledged ahead of its answer (owed) may still be refused: the
        # printer can ask for it (left out, a request for it was read as a garbled one
        # for the line after, refused by number in a loop that only a reset ended)
        acks, writer = self.core.acks, self.core.writer
        low = min([*self.window.numbers(), *acks.answers_owed, acks.last_acked_number + 1,
                   writer.next_number])
        candidates = range(low, writer.next_number + 1)
        number = resolve_resend(response.digits, candidates, error_line)
        if number is None:
            number = self._repeated_implausible(response, error_line)
            if number is None:
                self.stats.implausible_resends += 1
                return
        self._implausible = ("", 0)
        if error_before is None and not self._confirm_unannounced(number):
            return
        if number <= self.core.acks.last_acked_number:
            if implied:
                # only the Error's Last Line names it (its Resend lost): a digit of it
                # changed by noise ("Last Line: 3?" for 35) would take back every
                # acknowledgement since and replay lines that ran. The printer refuses
                # the next line too, with a Resend that says
                self.stats.implausible_resends += 1
                return
            far = self.core.acks.last_acked_number - number > self.window.max_lines + 4
            lost = error_line == 0 and number == 1 and not implied
            if number not in self.core.writer.history or (far and number == 1) or lost:
                # the printer lost its line number (a reset whose banner was lost, or a
                # firmware that prints none: "Last Line: 0" only a reset or M110 gives)
                self.core.on_reset()
                return
            # oks counted for lines the printer refused (a mangled line it answered as an
            # unknown command, noise on the oks): it holds every line before `number` and
            # none from it, so take the acknowledgements back and replay; a renumbering
            # to the last line acknowledged would skip the lines it never took
            self.core.acks.take_back(number)
            if not self.core.stopping:
                # the lines it names may have been taken after all (the request came late),
                # and a firmware that drops a repeated line silently answers their copies
                # with nothing: a probe after the replay says where the printer is
                self.core.acks.resolve_by_probe()
                self._ask_probe()
        model = self.model
        if error_line is not None:
            model.holds(error_line)
        # two lines agreeing (the Error's Last Line and the Resend's number, as received)
        confirmed = (not implied and error_line is not None and error_line + 1 == number
                     and response.digits == str(number))
        released = (confirmed and error_line is not None
                    and error_line > self.core.acks.last_acked_number
                    and self.window.release(error_line))
        if confirmed and not released and number == model.skipped:
            # asked again for the line a skipped replay left to the printer: this time
            # it did not take the lines behind the refusal (it drained them, as Marlin
            # does after an error); replay as before from now on
            model.learn_keeps_buffer(False)
        if released and not self.core.stopping:
            # the printer has read the lines up to its Last Line: they leave its receive
            # buffer (and the window), but whether their oks come is the firmware's choice
            # (an emulation answers the refused next line with the only ok the last line
            # gets); a probe right away tells, instead of a full window waiting out the
            # silence for one. Until it is answered no job line goes out: with nothing but
            # the probe after them, its ok T: is the first answer past those lines, and
            # acknowledges them however many oks the firmware gave them. Once its answers
            # showed that the ok after the Resend stands in for that line (the model's
            # ``stands_in``), that ok is counted for it instead, where no replay follows
            unreplayed = self.core.config.ok_after_resend \
                and self._ends_without_replay(number, error_line, confirmed)
            if unreplayed and model.trusts_stand_in():
                self.core.count_resend_ok()
                self.stats.stand_ins_counted += 1
            else:
                if unreplayed:
                    self.core.acks.stand_in_checks += 1
                self.core.acks.resolve_by_probe()
                self._ask_probe()
        if confirmed and error_line is not None and model.explains(error_line) \
                and model.refused != number and not self._refuses_oldest(number):
            # the printer took lines at or after the replay's start before their copies
            # arrived (the refusal that started it was spurious, or lines still on the wire
            # got through): those copies are refused, each once, and need no answer. (Once
            # resynchronised to ``number``, further refusals asking for it are echoes while
            # any are expected, then a refusal of ``number`` itself: taken for a new
            # resynchronisation each time, a line drained after a copy's refusal was
            # never written again)
            self._resync(number)
            return
        # a line behind a refused one is refused by its number; a checksum error names a
        # line numbered as asked, so it is the refusal of a copy (taken for an echo, that
        # copy was never replayed and the window waited for its ok)
        if number == model.refused and model.echoes > 0 and not (
                error_before is not None and error_before.error_kind == "checksum"
                and self._refuses_oldest(number)):
            model.echoes -= 1
            self.stats.duplicate_resends += 1
            if confirmed and error_line is not None:
                self.window.drop_copy(error_line)
            # the refusals counted as echoes may have included that of ``number`` itself
            # (drained behind a copy's refusal): if the printer goes quiet, a probe soon
            # (refused, it asks for ``number`` with no echo left) rather than after the
            # full silence
            self.core.acks.suspect(number in self.window.numbers())
            return
        if number >= self.core.writer.next_number:
            return  # the printer has every line sent: nothing to replay
        if released and model.keeps_buffer and self.core.writer.replay_next is None \
                and not any(e.copy for e in self.window):
            # a firmware seen to keep the lines behind such a refusal takes those in
            # flight in turn: their copies would each be refused as a duplicate (one
            # more refusal and round trip each). Should it drain them after all, the
            # next line it reads is refused asking for ``number`` again, replayed then
            model.skipped = number
            self.stats.replays_skipped += 1
            return
        self.replay_from(number)
        model.after_release = bool(released)

    def _ends_without_replay(self, number: int, error_line: int | None,
                             confirmed: bool) -> bool:
        """True when a refusal that released lines ends below with no replay and no
        resynchronisation, on a firmware seen to keep the lines behind a refusal: the
        printer has every line sent, or takes those behind it in turn (the same tests, in
        the same order, as :meth:`on_resend` makes).

        Only there is the ok after the Resend counted for the released line: a firmware
        that drains its buffer after an error is Marlin or like it, and Marlin answers a
        line it read when it has run it, after the refusal that named it. (The seeded
        loop's next_line dialect, a Marlin that also refuses as the emulation does, lost
        a line when such an ok was counted twice.)"""
        model = self.model
        if not model.keeps_buffer:
            return False
        if confirmed and error_line is not None and model.explains(error_line):
            return False
        if number == model.refused and model.echoes > 0:
            return False
        writer = self.core.writer
        if number >= writer.next_number:
            return True
        return writer.replay_next is None and not any(e.copy for e in self.window)

    def replay_from(self, number: int) -> None:
        """The printer refused line ``number`` (and drains or refuses those after it):
        write them again from there, with a narrower window."""
        self.window.shrink()
        # probes from the refused line on are replayed: their copies' answers are counted
        self.core.acks.drop_owed_from(number)
        dropped = self.window.drop_from(number)
        self.model.replaying(number, len(dropped) - 1, top=self.core.writer.next_number - 1)
        self.core.writer.replay_at(number)

    def _refuses_oldest(self, number: int) -> bool:
        """True when a refusal asking for ``number`` can only be that of the oldest line in
        flight, a copy of ``number`` itself: no copy of a line the printer holds is still
        in flight to be refused instead. (A firmware that keeps its receive buffer after
        an error refuses the lines behind it in turn; taken for the echo of a held copy,
        that refusal was answered by nothing and the stream waited for a probe.)"""
        oldest = self.window.oldest()
        if oldest is None or oldest.number != number:
            return False
        if not oldest.copy:
            # an original: only when no refusal of a copy is still expected either
            return self.model.echoes == 0 and not any(e.copy for e in self.window)
        return not any(e.copy and e.number is not None and e.number < number
                       for e in self.window)

    def _ask_probe(self) -> None:
        """An ``M105`` as the next line the link adds, unless one is already out or
        queued: its ``ok T:`` acknowledges every line before it."""
        if any(c.probe for c in self.core.writer.control) or any(
                e.probe for e in self.window if not e.held and not e.copy):
            return
        self.core.writer.queue_control("M105", internal=True, probe=True, front=True)

    def _resync(self, number: int) -> None:
        """A refusal whose ``Last Line`` is past the replay's start: the printer took those
        lines before their copies arrived (the refusal that started the replay was spurious,
        or lines still on the wire got through) and needs ``number`` next. The copies of the
        lines it holds are refused, one refusal each (echoes, answered by nothing); a copy
        of ``number`` written after them will be taken. The replay skips what is held."""
        model = self.model
        refused = model.refused
        assert refused is not None  # a replay is under way (``model.explains``)
        # the copies still to be refused are those of held lines in the window (a copy
        # whose ok was counted for another line is refused too: one more at most)
        out = sum(1 for e in self.window if e.copy and e.number is not None
                  and refused <= e.number < number)
        if model.after_release:
            # the replay began at a refusal naming a line in flight as the last one read,
            # and the printer had taken lines after it: it keeps its receive buffer then
            model.learn_keeps_buffer(True)
        model.advanced(number, max(0, out - 1) + 1)
        self.window.drop_copy(number - 1)
        self.stats.duplicate_resends += 1
        self.core.writer.skip_replay_to(number)

    def _refused_during_renumber(self, error_before: Response | None) -> None:
        renumber = self.core.writer.renumber
        assert renumber is not None  # called while renumbering
        if renumber.writes:
            renumber.refusals += 1
        # M110 skips the line-number check, so only a checksum error can refuse it; a
        # line-number error comes from a line sent before it (before the reset)
        refused = error_before is not None and error_before.error_kind != "line_number"
        if renumber.sent and refused:
            self.window.clear()
            renumber.sent = False
        else:
            self.stats.duplicate_resends += 1

    def _confirm_unannounced(self, number: int) -> bool:
        """Marlin announces every resend with an ``Error:`` line. A request without one (the
        error line lost to noise, or a spurious request) is obeyed only when repeated: if
        the printer really lacks the line, it refuses the next line with an error."""
        previous, count = self._unconfirmed
        count = count + 1 if previous == number else 1
        self._unconfirmed = (number, count)
        if count >= 2:
            self._unconfirmed = (-1, 0)
            return True
        self.stats.unconfirmed_resends += 1
        return False

    def _repeated_implausible(self, response: Response, error_line: int | None) -> int | None:
        """A request repeated three times, or confirmed by the error's ``Last Line``, for a
        line not yet acknowledged and still held, is obeyed after all; one for an
        acknowledged line is returned too (the caller treats it as lost state)."""
        digits, count = self._implausible
        count = count + 1 if digits == response.digits else 1
        self._implausible = (response.digits, count)
        number = response.line
        if number is None or number > self.core.writer.next_number:
            return None
        confirmed = error_line is not None and error_line + 1 == number
        if count >= 3 or confirmed:
            self._implausible = ("", 0)
            if number <= self.core.acks.last_acked_number or number in self.core.writer.history:
                return number
        return None
