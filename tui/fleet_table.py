"""A table that draws only its visible rows, each from a cache: thousands of rows stay cheap.

Textual's DataTable re-renders every visible cell whenever any cell changes;
here a changed row costs one cached line, and only when it is on screen.
"""

from __future__ import annotations

from typing import ClassVar

from rich.cells import set_cell_size
from rich.segment import Segment
from rich.style import Style
from textual.binding import Binding
from textual.events import Click
from textual.geometry import Region, Size
from textual.message import Message
from textual.scroll_view import ScrollView
from textual.strip import Strip

from tui.fleet_model import COLUMNS

FLEX_COLUMN = "job"  # takes the width the others leave
GAP = " "
STATE_STYLES = {
    "error": Style(color="red", bold=True),
    "offline": Style(color="magenta", bold=True),
    "paused": Style(color="yellow"),
    "heating": Style(color="dark_orange"),
    "printing": Style(color="green"),
    "idle": Style(dim=True),
}
PROGRESS_STYLE = Style(color="cyan")


def column_widths(total: int) -> list[int]:
    """Each column's width for a table ``total`` cells wide (the job column flexes)."""
    fixed = sum(width for key, _, width in COLUMNS if key != FLEX_COLUMN)
    spare = total - fixed - len(GAP) * len(COLUMNS)
    return [max(8, spare) if key == FLEX_COLUMN else width for key, _, width in COLUMNS]


def header_text(total: int) -> str:
    """The column headings laid out as the rows are."""
    widths = column_widths(total)
    return GAP + GAP.join(set_cell_size(label, w) for (_, label, _), w in zip(
        COLUMNS, widths, strict=True))


def changed_columns(old: tuple[str, ...], new: tuple[str, ...],
                    total: int) -> list[tuple[int, int]]:
    """(first cell, cells) of each column whose text differs, in a row ``total`` wide."""
    out = []
    x = len(GAP)
    for size, before, after in zip(column_widths(total), old, new, strict=True):
        if before != after:
            out.append((x, size))
        x += size + len(GAP)
    return out


class FleetTable(ScrollView, can_focus=True):
    """Rows of printers (ids and cell texts) in a given order, with a row cursor."""

    COMPONENT_CLASSES: ClassVar[set[str]] = {"fleet-table--cursor"}
    DEFAULT_CSS = """
    FleetTable { height: 1fr; overflow-x: hidden; }
    FleetTable > .fleet-table--cursor { background: $accent 40%; text-style: bold; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("up", "move(-1)", "Up", show=False),
        Binding("down", "move(1)", "Down", show=False),
        Binding("pageup", "page(-1)", "Page up", show=False),
        Binding("pagedown", "page(1)", "Page down", show=False),
        Binding("home", "move(-1000000000)", "First", show=False),
        Binding("end", "move(1000000000)", "Last", show=False),
        Binding("enter", "choose", "Open"),
    ]

    class Chosen(Message):
        """Enter (or a click on the row under the cursor) chose a printer."""

        def __init__(self, printer: str) -> None:
            super().__init__()
            self.printer = printer

    def __init__(self, *, id: str | None = None) -> None:
        super().__init__(id=id)
        self.order: list[str] = []
        self.cells: dict[str, tuple[str, ...]] = {}
        self.cursor = 0
        self._index: dict[str, int] = {}
        self._strips: dict[str, Strip] = {}
        self._width = 0

    @property
    def row_count(self) -> int:
        """Number of rows."""
        return len(self.order)

    def row_at(self, index: int) -> tuple[str, ...]:
        """The cell texts of row ``index`` (0 = top)."""
        return self.cells[self.order[index]]

    def cursor_printer(self) -> str | None:
        """The printer under the cursor, if any."""
        return self.order[self.cursor] if self.order else None

    def set_rows(self, order: list[str], cells: dict[str, tuple[str, ...]]) -> None:
        """Show ``order`` (printer ids) with their cells; the cursor stays on its printer,
        or at the top when it was there."""
        current = self.cursor_printer() if self.cursor > 0 else None
        self.order = order
        self.cells = dict(cells)  # its own: update_row compares with what it shows
        self._index = {printer: n for n, printer in enumerate(order)}
        self._strips = {p: s for p, s in self._strips.items() if p in self._index}
        self.cursor = self._index.get(current, 0) if current is not None else 0
        self.cursor = min(self.cursor, max(0, len(order) - 1))
        self.virtual_size = Size(0, len(order))
        self.refresh()

    def update_row(self, printer: str, cells: tuple[str, ...]) -> None:
        """New cells for one shown printer; if its line is on screen, redraws the
        columns that changed (only those cross to the terminal)."""
        old = self.cells.get(printer)
        self.cells[printer] = cells
        self._strips.pop(printer, None)
        row = self._index.get(printer)
        if row is None:
            return
        y = row - int(self.scroll_offset.y)
        if not 0 <= y < self.scrollable_content_region.height:
            return
        if old is None or len(old) != len(cells):
            self.refresh(Region(0, y, self.row_width, 1))
            return
        for x, width in changed_columns(old, cells, self.row_width):
            self.refresh(Region(x, y, width, 1))

    def _strip(self, printer: str, width: int) -> Strip:
        strip = self._strips.get(printer)
        if strip is None or self._width != width:
            if self._width != width:
                self._strips.clear()
                self._width = width
            segments = [Segment(GAP)]
            for (key, _, _), size, text in zip(COLUMNS, column_widths(width),
                                               self.cells[printer], strict=True):
                style = (STATE_STYLES.get(text, STATE_STYLES["error"]) if key == "state"
                         else PROGRESS_STYLE if key == "progress" else None)
                segments += [Segment(set_cell_size(text, size), style), Segment(GAP)]
            strip = Strip(segments).crop_extend(0, width, None)
            self._strips[printer] = strip
        return strip

    @property
    def row_width(self) -> int:
        """Cells across a row (the width left beside the scrollbar)."""
        return self.scrollable_content_region.width

    def render_line(self, y: int) -> Strip:
        width = self.row_width
        row = y + int(self.scroll_offset.y)
        base = self.rich_style
        if row >= len(self.order):
            return Strip.blank(width, base)
        strip = self._strip(self.order[row], width).apply_style(base)
        if row == self.cursor and self.has_focus:
            strip = strip.apply_style(self.get_component_rich_style("fleet-table--cursor"))
        elif row == self.cursor:
            strip = strip.apply_style(Style(reverse=True))
        return strip

    def on_resize(self) -> None:
        self.virtual_size = Size(0, len(self.order))

    def _show_cursor(self) -> None:
        top = int(self.scroll_offset.y)
        height = self.scrollable_content_region.height
        if self.cursor < top:
            self.scroll_to(y=self.cursor, animate=False)
        elif self.cursor >= top + height:
            self.scroll_to(y=self.cursor - height + 1, animate=False)
        self.refresh()

    def action_move(self, step: int) -> None:
        if self.order:
            self.cursor = min(max(self.cursor + step, 0), len(self.order) - 1)
            self._show_cursor()

    def action_page(self, pages: int) -> None:
        self.action_move(pages * max(1, self.scrollable_content_region.height - 1))

    def action_choose(self) -> None:
        printer = self.cursor_printer()
        if printer is not None:
            self.post_message(self.Chosen(printer))

    def on_click(self, event: Click) -> None:
        row = event.y + int(self.scroll_offset.y)
        if 0 <= row < len(self.order):
            if row == self.cursor or event.chain > 1:
                self.cursor = row
                self.action_choose()
            self.cursor = row
            self.refresh()

    def on_focus(self) -> None:
        self.refresh()

    def on_blur(self) -> None:
        self.refresh()
