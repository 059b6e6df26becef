"""The event log: one line per event, cut at a word to the log's width, never wrapped."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rich.text import Text
from textual.events import Resize
from textual.widgets import RichLog

from tui.format import clock, fit_words

Entry = tuple[float, str, str]  # Unix time, colour, text
STAMP = len("HH:MM:SS ")


class EventLog(RichLog):
    """Shows entries (time, colour, text), newest last, each on one line of the log.

    A line longer than the log ends in ``…`` after its last whole word; the
    entries are kept whole, so a wider log (a wider terminal) shows more of
    them: every resize lays the lines out again.
    """

    def __init__(self, max_lines: int, **kwargs: Any) -> None:
        super().__init__(markup=False, wrap=False, max_lines=max_lines, min_width=1, **kwargs)
        self.entries: list[Entry] = []
        self._laid_out_at = 0  # the width the lines were cut for (0: not laid out yet)

    def add(self, entry: Entry) -> None:
        """Append one entry (the oldest goes beyond ``max_lines``)."""
        self.entries.append(entry)
        if self.max_lines is not None:
            del self.entries[:-self.max_lines]
        if self._laid_out_at:
            # scrolled at once, not after the next refresh: one repaint per entry, not two
            self.write(self._line(entry), width=self._laid_out_at, scroll_end=False)
            if self.auto_scroll:
                self.scroll_end(animate=False, immediate=True, x_axis=False)

    def show(self, entries: Iterable[Entry]) -> None:
        """Replace every line with ``entries``."""
        self.entries = list(entries)
        self._lay_out()

    def line_width(self) -> int:
        """The cells a line may take: the log's width less its scrollbar."""
        return self.scrollable_content_region.width

    def on_resize(self, event: Resize) -> None:
        if self.line_width() > 0 and self.line_width() != self._laid_out_at:
            self._size_known = True  # nothing is ever deferred: lines wait for a width here
            self._lay_out()

    def _lay_out(self) -> None:
        self.clear()
        self._laid_out_at = self.line_width()
        if self._laid_out_at <= 0:
            self._laid_out_at = 0
            return
        for entry in self.entries:
            self.write(self._line(entry), width=self._laid_out_at)

    def _line(self, entry: Entry) -> Text:
        ts, colour, text = entry
        fitted = fit_words(f"{clock(ts)} {text}", self._laid_out_at)
        return Text.assemble((fitted[:STAMP], "dim"), (fitted[STAMP:], colour),
                             no_wrap=True, overflow="crop")
