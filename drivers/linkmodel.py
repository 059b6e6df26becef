"""The protocol core's model of the printer: which lines it holds, refused, or may still get."""

from __future__ import annotations

from dataclasses import dataclass


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
    """

    held: int = 0
    refused: int | None = None
    echoes: int = 0

    def holds(self, number: int) -> None:
        """Line ``number`` is known to be in the firmware (and so is every earlier one)."""
        if number > self.held:
            self.held = number

    def replaying(self, number: int, echoes: int) -> None:
        """A replay starts at ``number``; ``echoes`` copies written before it are still out."""
        self.refused = number
        self.echoes = echoes

    def settled(self) -> None:
        """No refusal still expected."""
        self.refused = None
        self.echoes = 0

    def renumbered(self, value: int) -> None:
        """``M110 N<value>`` took effect."""
        self.held = value
        self.settled()

    def lost(self) -> None:
        """The printer reset or the port was cut: it holds nothing in flight."""
        self.settled()
