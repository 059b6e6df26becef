"""The protocol core's model of the printer: which lines it holds, refused, or may still get."""

from __future__ import annotations

from dataclasses import dataclass

# refusals whose Resend's ok was seen to stand in for the line named as the last read
# before that is trusted (and none seen otherwise), and one such refusal in this many is
# checked by a probe all the same (a firmware that answers the line after all unlearns it
# there, for good). With 2, the seeded loop's next_line dialect (a Marlin that also refuses
# as the emulation does) overran the receive buffer once in 2,000 runs; with 3, as often
# as before (seeds 0-2000)
STAND_IN_SEEN = 3
STAND_IN_CHECK = 4


@dataclass
class PrinterModel:
    """What the link knows of the firmware's line bookkeeping (current numbering).

    - ``held``: every line up to this number is in the firmware (acknowledged, or named by
      the ``Last Line`` of a refusal); lines after it that were written and not yet
      acknowledged are in the window, i.e. still on the wire or in its buffers.
    - ``refused``: the line a replay started from after the printer refused it (``None``:
      no replay since the last resynchronisation).
    - ``echoes``: refusals still expected for that line from copies written before the
      replay (each line behind a refused one is refused too, or silently drained).
    - ``first`` / ``copied``: the lines the replay has written again so far (copies), and
      ``top`` the last line written before it began. A copy can only be refused with a
      ``Last Line`` from ``first`` to ``max(top, copied)``: the printer cannot hold a
      line written after the copy before it reads the copy.
    - ``keeps_buffer``: learned on this connection, the firmware takes the lines behind a
      refusal that named a line in flight as its last (it keeps its receive buffer after
      such an error): a copy of a line after it was refused as one it already had.
      ``skipped``: the line such a refusal asked for, not replayed on that account;
      ``after_release``: the replay under way began at such a refusal.
    - ``stands_in``: learned on this connection, the ``ok`` the firmware sends after the
      ``Resend`` of such a refusal is the only one the line named as the last read gets
      (OctoPrint's virtual printer: the line is taken by number and its command dropped),
      where Marlin answers that line with an ok of its own. Seen ``STAND_IN_SEEN`` times
      and never otherwise, on a firmware that keeps its buffer, the ok is counted for the
      line and no probe is asked; ``stand_ins_seen`` is -1 once it was seen otherwise;
      ``unchecked``: such refusals since a probe last checked it.
    """

    held: int = 0
    refused: int | None = None
    echoes: int = 0
    first: int = 0
    copied: int = -1
    top: int = -1
    keeps_buffer: bool = False
    after_release: bool = False
    skipped: int | None = None
    stand_ins_seen: int = 0
    unchecked: int = 0

    def holds(self, number: int) -> None:
        """Line ``number`` is known to be in the firmware (and so is every earlier one)."""
        if number > self.held:
            self.held = number

    def replaying(self, number: int, echoes: int, top: int) -> None:
        """A replay starts at ``number`` after lines up to ``top`` were written; ``echoes``
        refusals are still expected from lines written before it."""
        self.refused = number
        self.echoes = max(0, echoes)
        self.after_release = False
        self.first = number
        self.copied = number - 1
        self.top = top

    def explains(self, last_line: int) -> bool:
        """True if a copy written by the replay may have been refused with ``last_line``:
        the printer holds a line at or after the replay's start."""
        return (self.refused is not None and self.copied >= self.first
                and self.refused <= last_line <= max(self.top, self.copied))

    def advanced(self, number: int, echoes: int) -> None:
        """The printer holds up to ``number - 1`` past the replay's start: the copies of
        held lines still out are refused, one refusal each (``echoes``), and ``number``
        is needed next."""
        self.echoes = max(0, echoes)
        self.refused = number

    def copy(self, number: int) -> None:
        """Line ``number`` was written again by the replay."""
        if self.refused is not None and number > self.copied:
            self.copied = number

    def settled(self) -> None:
        """No refusal still expected."""
        self.refused = None
        self.echoes = 0
        self.first = 0
        self.copied = -1
        self.top = -1

    def renumbered(self, value: int) -> None:
        """``M110 N<value>`` took effect."""
        self.held = value
        self.settled()

    def learn_keeps_buffer(self, keeps: bool) -> None:
        """What the firmware showed it does with the lines behind a refusal."""
        self.keeps_buffer = keeps
        self.skipped = None

    def saw_stand_in(self, stood_in: bool) -> None:
        """A probe's answer showed whether the ``ok`` after a refusal's ``Resend`` stood in
        for the line it named as the last read (``stood_in``), or that line had its own."""
        self.unchecked = 0
        if not stood_in:
            # a firmware seen to answer such a line itself, once, may do so again: the
            # ok counted for it would put the count a line ahead of the printer (a line
            # written past its receive buffer). Never trusted again on this connection
            self.stand_ins_seen = -1
        elif self.stand_ins_seen >= 0:
            self.stand_ins_seen += 1

    @property
    def stands_in(self) -> bool:
        """Learned: the ok after such a refusal's ``Resend`` stands in for the line's."""
        return self.stand_ins_seen >= STAND_IN_SEEN

    def trusts_stand_in(self) -> bool:
        """True when the ``ok`` after this refusal's ``Resend`` is counted for the line it
        named and no probe checks it; every ``STAND_IN_CHECK``-th such refusal is checked."""
        if not self.stands_in:
            return False
        self.unchecked += 1
        return self.unchecked < STAND_IN_CHECK

    def forget_stand_in(self) -> None:
        """A new connection: nothing learned of its oks yet."""
        self.stand_ins_seen = 0
        self.unchecked = 0

    def lost(self) -> None:
        """The printer reset or the port was cut: it holds nothing in flight."""
        self.settled()
