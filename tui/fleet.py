"""The fleet view: every printer on an MQTT broker in one table, problems first."""

from __future__ import annotations

import time
from typing import Any, ClassVar, Protocol

from rich.text import Text
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.message import Message
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Input, Static

from tui.fleet_model import COLUMNS, COUNTED, FleetModel, matches, row_cells
from tui.fleet_printer import printer_screen
from tui.sources import AvailabilityItem, EventItem, Source, StatusItem

STYLES = {
    "error": "bold red",
    "offline": "bold magenta",
    "paused": "yellow",
    "heating": "dark_orange",
    "printing": "green",
    "idle": "dim",
}


class FleetSource(Source, Protocol):
    """A source that follows many printers and can hand out one printer's source."""

    def fleet_stream(self) -> Any: ...

    def for_printer(self, printer: str) -> Source: ...


class OpenPrinter(Message):
    """The user chose a printer in the fleet table (Enter or a click)."""

    def __init__(self, printer_id: str) -> None:
        super().__init__()
        self.printer_id = printer_id


def _styled(column: str, value: str) -> str | Text:
    if column == "state":
        return Text(value, style=STYLES.get(value, "bold red"))
    if column == "progress" and value:
        return Text(value, style="cyan")
    return value


class FleetScreen(Screen[None]):
    """The fleet table, its per-state counts and a filter; redrawn a few times a second.

    Status messages only update the model; a timer applies what changed to the
    table: changed cells in place, and a re-sort only when a printer's place
    changes (a new printer, another state, the filter).
    """

    CSS = """
    #counts { height: 1; padding: 0 1; background: $boost; }
    #filter { display: none; height: 3; }
    #filter.shown { display: block; }
    #fleet { height: 1fr; }
    #note { height: 1; padding: 0 1; color: $text-muted; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("slash", "filter", "Filter"),
        Binding("escape", "clear_filter", "Clear filter", show=False),
        Binding("q", "app.quit", "Quit"),
    ]

    def __init__(self, source: FleetSource, *, refresh_s: float = 0.25) -> None:
        super().__init__()
        self.source = source
        self.model = FleetModel()
        self.query_text = ""
        self.refresh_s = refresh_s
        self.note = ""
        self.collect_stamps = False  # True: rows_shown() gets each shown status' timestamp
        self._shown: dict[str, tuple[str, ...]] = {}

    def compose(self) -> ComposeResult:
        yield Static("waiting for printers...", id="counts")
        yield Input(placeholder="filter by name, job or state; Enter keeps it, Esc clears",
                    id="filter")
        yield DataTable(id="fleet", cursor_type="row", zebra_stripes=True)
        yield Static("", id="note")
        yield Footer()

    @property
    def table(self) -> DataTable[Any]:
        return self.query_one("#fleet", DataTable)

    def on_mount(self) -> None:
        table = self.table
        for key, label, width in COLUMNS:
            table.add_column(label, key=key, width=width)
        self.sub_title = self.source.label
        self.set_interval(self.refresh_s, self.flush)
        self.run_worker(self._pump(), name="fleet-pump", exclusive=True)
        table.focus()

    async def _pump(self) -> None:
        model = self.model
        async for item in self.source.fleet_stream():
            if isinstance(item, StatusItem):
                if item.printer:
                    model.put_status(item.printer, item.snapshot)
                else:
                    self.note = f"[red]{item.snapshot.error or 'broker unreachable'}[/]"
            elif isinstance(item, AvailabilityItem):
                model.put_online(item.printer, item.online)
            elif isinstance(item, EventItem):
                self._event(item)

    def _event(self, item: EventItem) -> None:
        event = item.event
        if event.get("event") != "error":
            return
        stamp = time.strftime("%H:%M:%S", time.localtime(float(event.get("ts") or time.time())))
        cmd = event.get("cmd") or "command"
        self.note = f"{stamp} [b]{item.printer}[/b] refused {cmd}: [red]{event.get('reason')}[/]"

    def flush(self) -> None:
        """Apply the changes since the last flush to the table and the counts."""
        dirty = self.model.take_dirty()
        self.query_one("#note", Static).update(self.note)
        if not dirty:
            return
        table, model, query = self.table, self.model, self.query_text
        stamps: list[float] = []
        reorder = False
        for printer in sorted(dirty):
            entry = model.entries[printer]
            cells = row_cells(printer, entry)
            old = self._shown.get(printer)
            visible = not query or matches(printer, entry, query)
            if visible and entry.snapshot is not None:
                stamps.append(entry.snapshot.ts)
            if old is None and visible:
                table.add_row(*(_styled(k, v) for (k, _, _), v in zip(COLUMNS, cells, strict=True)),
                              key=printer)
                self._shown[printer] = cells
                reorder = True
            elif old is not None and not visible:
                table.remove_row(printer)
                del self._shown[printer]
            elif old is not None and old != cells:
                for (key, _, _), before, after in zip(COLUMNS, old, cells, strict=True):
                    if before != after:
                        table.update_cell(printer, key, _styled(key, after))
                reorder = reorder or old[1] != cells[1]
                self._shown[printer] = cells
        if reorder:
            self._sort()
        self._show_counts()
        if self.collect_stamps and stamps:
            self.call_after_refresh(self.rows_shown, stamps)

    def rows_shown(self, stamps: list[float]) -> None:
        """Called after the screen shows statuses stamped ``stamps`` (for measurements)."""

    def _sort(self) -> None:
        table = self.table
        # the cursor stays on its printer, or at the top (the worst problem) when there
        current = self.cursor_printer() if table.cursor_row > 0 else None
        table.sort("printer", key=lambda name: self.model.sort_key(str(name)))
        if current is not None and current in self._shown:
            table.move_cursor(row=table.get_row_index(current), scroll=False)

    def cursor_printer(self) -> str | None:
        """The id of the printer under the cursor, if any."""
        table = self.table
        if table.row_count == 0:
            return None
        return str(table.coordinate_to_cell_key(table.cursor_coordinate).row_key.value)

    def _show_counts(self) -> None:
        counts = self.model.counts()
        total = len(self.model.entries)
        parts = [f"[b]{total}[/b] printers on {self.source.label}"]
        if self.query_text:
            parts[0] += f" ([b]{len(self._shown)}[/b] shown for '{self.query_text}')"
        for state in COUNTED:
            if counts[state] or state in ("error", "offline", "printing", "idle"):
                parts.append(f"[{STYLES[state]}]{state}[/] {counts[state]}")
        self.query_one("#counts", Static).update("  ".join(parts))

    def rebuild(self) -> None:
        """Refill the table from the model (after the filter changed)."""
        table, model = self.table, self.model
        current = self.cursor_printer()
        table.clear()
        self._shown.clear()
        self.model.take_dirty()
        for printer in model.ordered(self.query_text):
            cells = row_cells(printer, model.entries[printer])
            table.add_row(*(_styled(k, v) for (k, _, _), v in zip(COLUMNS, cells, strict=True)),
                          key=printer)
            self._shown[printer] = cells
        if current is not None and current in self._shown:
            table.move_cursor(row=table.get_row_index(current))
        self._show_counts()

    def action_filter(self) -> None:
        box = self.query_one("#filter", Input)
        box.add_class("shown")
        box.focus()

    def action_clear_filter(self) -> None:
        box = self.query_one("#filter", Input)
        box.remove_class("shown")
        if box.value:
            box.value = ""  # Input.Changed rebuilds the table
        self.table.focus()

    def on_input_changed(self, message: Input.Changed) -> None:
        self.query_text = message.value.strip()
        self.rebuild()

    def on_input_submitted(self, message: Input.Submitted) -> None:
        if not message.value.strip():
            message.input.remove_class("shown")
        self.table.focus()

    def on_data_table_row_selected(self, message: DataTable.RowSelected) -> None:
        self.post_message(OpenPrinter(str(message.row_key.value)))


class FleetApp(App[None]):
    """``hostd tui --mqtt``: the fleet table; Enter opens one printer over MQTT."""

    TITLE = "hostd fleet"

    def __init__(self, source: FleetSource, *, refresh_s: float = 0.25) -> None:
        super().__init__()
        self.source = source
        self.refresh_s = refresh_s

    def on_mount(self) -> None:
        self.push_screen(FleetScreen(self.source, refresh_s=self.refresh_s))

    def on_open_printer(self, message: OpenPrinter) -> None:
        self.push_screen(printer_screen(self.source.for_printer(message.printer_id),
                                        message.printer_id))
