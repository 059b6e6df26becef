"""A widget drawn as one line of text per row, repainting only the rows that change.

Textual rewrites the whole region of a refreshed widget on the terminal; over a
slow link (SSH) that is what costs. A :class:`LinesWidget` keeps the lines it
shows and, on :meth:`LinesWidget.redraw`, compares them with the new ones and
refreshes only the cells that differ, row by row: a status that changes one
number costs those few cells on the terminal, not the panel.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, Self

from rich.cells import cell_len
from rich.console import Group
from rich.style import Style
from rich.text import Text
from textual.geometry import Region, Size
from textual.widget import Widget


def changed_runs(old: Sequence[Text], new: Sequence[Text]) -> Iterator[tuple[int, int]]:
    """(first row, rows) of each run of consecutive rows that differ between two texts."""
    start = None
    for row in range(max(len(old), len(new))):
        same = row < len(old) and row < len(new) and old[row] == new[row]
        if not same and start is None:
            start = row
        elif same and start is not None:
            yield start, row - start
            start = None
    if start is not None:
        yield start, max(len(old), len(new)) - start


MERGE_GAP = 8  # unchanged cells between two changes of a row sent anyway (a cursor move costs)


def _marks(text: Text) -> list[tuple[str | Style, ...]]:
    """The styles of the spans over each character of ``text``, in order."""
    marks: list[tuple[str | Style, ...]] = [()] * len(text.plain)
    for span in text.spans:
        for i in range(span.start, min(span.end, len(marks))):
            marks[i] = (*marks[i], span.style)
    return marks


def changed_cells(old: Text, new: Text, width: int) -> list[tuple[int, int]]:
    """(first cell, cells) of each stretch of a row that differs between two texts of it.

    Runs closer than ``MERGE_GAP`` cells are joined. A text with wide characters,
    another base style, or one longer than ``width`` (cut with ``…`` where the
    row ends) is repainted from its first change to the end of the row.
    """
    a, b = old.plain, new.plain
    simple = (old.style == new.style and cell_len(a) == len(a) and cell_len(b) == len(b))
    if not simple:
        return [(0, width)]
    ma, mb = _marks(old), _marks(new)
    longest = max(len(a), len(b))
    differ = [i for i in range(longest)
              if i >= len(a) or i >= len(b) or a[i] != b[i] or ma[i] != mb[i]]
    if not differ:
        return []
    if longest > width:  # the ellipsis may move: repaint to the end of the row
        first = min(differ[0], width - 1)
        return [(first, width - first)] if first < width else []
    runs: list[list[int]] = [[differ[0], differ[0] + 1]]
    for i in differ[1:]:
        if i - runs[-1][1] < MERGE_GAP:
            runs[-1][1] = i + 1
        else:
            runs.append([i, i + 1])
    return [(start, stop - start) for start, stop in runs if start < width]


class LinesWidget(Widget):
    """Content given as one Rich ``Text`` per row by :meth:`content_lines`.

    Call :meth:`redraw` (not ``refresh``) when the data behind the lines change.
    ``repainted_rows`` and ``repainted_cells`` count the rows and cells it asked
    Textual to repaint (a whole repaint counts them all), for tests and profiles.
    """

    _top_row_only = False  # set_border_title() is changing the title

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._lines: list[Text] | None = None
        self._lines_size: Size | None = None
        self._fresh = False  # the lines were computed by redraw() and not rendered yet
        self.repainted_rows = 0
        self.repainted_cells = 0

    def content_lines(self, width: int, height: int) -> list[Text]:
        """The lines to show in ``width`` x ``height`` cells, one per row (override)."""
        raise NotImplementedError

    def redraw(self) -> None:
        """Compute the lines again; repaint the rows that changed (all after a resize)."""
        size = self.content_size
        old = self._lines if self._lines_size == size else None
        new = self.content_lines(size.width, size.height)
        self._lines, self._lines_size, self._fresh = new, size, True
        if old is None:
            self.repainted_rows += max(1, size.height)
            self.repainted_cells += max(1, size.height) * size.width
            self.refresh()
            return
        for start, rows in changed_runs(old, new):
            self.repainted_rows += rows
            for y in range(start, start + rows):
                spans = ([(0, size.width)] if y >= len(old) or y >= len(new)
                         else changed_cells(old[y], new[y], size.width))
                for x, cells in spans:
                    self.repainted_cells += cells
                    self.refresh(Region(x, y, cells, 1))

    def set_border_title(self, title: str) -> None:
        """Change the border title, repainting only the border's top row (setting
        ``border_title`` repaints the whole widget, even with the same title)."""
        if title == self.border_title:
            return
        self._top_row_only = True
        try:
            self.border_title = title
        finally:
            self._top_row_only = False

    def refresh(self, *regions: Region, **kwargs: Any) -> Self:
        """As ``Widget.refresh``; while :meth:`set_border_title` runs, the top row only."""
        if self._top_row_only and not regions and not kwargs:
            offset = self.content_offset  # regions are given in content coordinates
            regions = (Region(-offset.x, -offset.y, self.outer_size.width, 1),)
        return super().refresh(*regions, **kwargs)

    def render(self) -> Group | Text:
        """The lines (computed again unless :meth:`redraw` just did, for this size); one
        line is returned as its text."""
        size = self.content_size
        if not self._fresh or self._lines is None or self._lines_size != size:
            self._lines, self._lines_size = self.content_lines(size.width, size.height), size
        self._fresh = False
        return self._lines[0] if len(self._lines) == 1 else Group(*self._lines)
