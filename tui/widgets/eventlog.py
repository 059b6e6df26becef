"""The event log: one line per event, cut at a word to the log's width, never wrapped."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from rich.text import Text
from textual.events import Resize
from textual.timer import Timer
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

    def __init__(self, max_lines: int, *, batch_s: float = 0.0, **kwargs: Any) -> None:
        super().__init__(markup=False, wrap=False, max_lines=max_lines, min_width=1, **kwargs)
        self.entries: list[Entry] = []
        self.batch_s = batch_s  # > 0 (a slow link): new lines shown at most this often
        self._laid_out_at = 0  # the width the lines were cut for (0: not laid out yet)
        self._pending: list[Entry] = []
        self._timer: Timer | None = None

    def add(self, entry: Entry) -> None:
        """Append one entry (the oldest goes beyond ``max_lines``); with ``batch_s``,
        the entries of ``batch_s`` seconds are shown together (every shown line
        moves up, so each showing repaints the whole log)."""
        self.entries.append(entry)
        if self.max_lines is not None:
            del self.entries[:-self.max_lines]
        if not self._laid_out_at:
            return
        self._pending.append(entry)
        if self.batch_s <= 0:
            self.flush()
        elif self._timer is None:
            self._timer = self.set_timer(self.batch_s, self.flush)

    def flush(self) -> None:
        """Show the entries added since the last showing, scrolled in the same update."""
        if self._timer is not None:
            self._timer.stop()
            self._timer = None
        pending, self._pending = self._pending, []
        for entry in pending:
            self.write(self._line(entry), width=self._laid_out_at, scroll_end=False)
        if pending and self.auto_scroll:  # at once, not after the next refresh: one repaint
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
        self._pending.clear()  # every entry is laid out here
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
