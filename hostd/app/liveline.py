"""A live progress line redrawn in place (``\\r``), never wider than the terminal is now."""

from __future__ import annotations

import contextlib
import os
import shutil
from typing import TextIO

from hostd.textforms import bar


def terminal_columns(stream: TextIO) -> int:
    """The width of the terminal ``stream`` writes to now; else ``$COLUMNS``, else 80.

    Read again at every call (the terminal may have been narrowed); at least 1,
    however narrow (a width of 0, as some pseudo-terminals report, means unknown).
    """
    with contextlib.suppress(AttributeError, OSError, ValueError):
        columns = os.get_terminal_size(stream.fileno()).columns
        if columns > 0:
            return columns
    return max(1, shutil.get_terminal_size((80, 24)).columns)


def fit_bar(fraction: float, tail: str, columns: int, widest: int = 30) -> str:
    """``[###---] tail`` in fewer than ``columns`` characters: the bar shrinks, then goes."""
    room = min(widest, columns - 1 - len(tail) - 3)
    if room < 5:
        return tail.strip()[: max(0, columns - 1)]
    return f"[{bar(fraction, room, ascii=True)}] {tail}"[: columns - 1]


class LiveLine:
    """One line on ``stream`` rewritten in place: cut to the terminal's width at each
    redraw, and padded with spaces only as far as the last line drawn reached *and*
    the terminal allows, so that no redraw ever runs past the right edge (a line
    that reached the edge would wrap, and the next ``\\r`` would leave it behind).

    The last column is never written: some terminals wrap as soon as it is.
    """

    def __init__(self, stream: TextIO, columns: int | None = None) -> None:
        self.stream = stream
        self.columns = columns  # fixed width (tests); None: the terminal's, read each time
        self._last = 0  # characters on the line now

    def width(self) -> int:
        """The characters a line may have now: one less than the terminal's columns."""
        columns = self.columns if self.columns is not None else terminal_columns(self.stream)
        return max(0, columns - 1)

    def draw(self, text: str) -> None:
        """Replace the line with ``text`` (cut to the width)."""
        room = self.width()
        text = text[:room]
        self.stream.write("\r" + text.ljust(min(self._last, room)))
        self._last = len(text)
        self.stream.flush()

    def clear(self) -> None:
        """Blank the line and put the cursor at its start."""
        room = self.width()
        self.stream.write("\r" + " " * min(self._last, room) + "\r")
        self._last = 0
        self.stream.flush()

    def end(self) -> None:
        """Leave the line as it is and go to the next one."""
        self.stream.write("\n")
        self._last = 0
        self.stream.flush()
