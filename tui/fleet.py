"""The fleet view: every printer on an MQTT broker in one table, problems first."""

from __future__ import annotations

import dataclasses
import time
from typing import Any, ClassVar, Protocol

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.screen import Screen
from textual.widgets import Footer, Input, Static

from hostd.api import Snapshot
from tui import partial_output
from tui.app import redraw_seconds
from tui.fleet_farm import FarmPanel, FarmRows
from tui.fleet_model import COUNTED, FleetModel, PrinterEntry, matches, row_cells
from tui.fleet_table import FleetTable, header_text
from tui.printer_screen import PrinterScreen
from tui.sources import GONE, AvailabilityItem, EventItem, Source, StatusItem

STYLES = {
    "error": "bold red",
    "offline": "bold magenta",
    "paused": "yellow",
    "heating": "dark_orange",
    "printing": "green",
    "idle": "dim",
}


class FleetSource(Source, Protocol):
    """A source that follows many printers: status, events and availability of each."""

    def fleet_stream(self) -> Any: ...


def shown_snapshot(entry: PrinterEntry) -> Snapshot | None:
    """The printer's last status as its own screen shows it (``offline`` after its last will)."""
    snap = entry.snapshot
    if entry.online is False:
        return dataclasses.replace(snap or Snapshot(), state="offline", error=GONE)
    return snap


class FleetScreen(Screen[None]):
    """The fleet table, its per-state counts and a filter; redrawn a few times a second.

    Status messages only update the model; a timer applies what changed to the
    table: a changed row is redrawn if it is on screen, and the rows are sorted
    again only when a printer's place changes (a new printer, another state, the
    filter).
    """

    CSS = """
    #counts { height: 1; padding: 0 1; background: $boost; }
    #filter { display: none; height: 3; }
    #filter.shown { display: block; }
    #columns { height: 1; text-style: bold; color: $text-muted; }
    #note { height: 1; padding: 0 1; color: $text-muted; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("slash", "filter", "Filter"),
        Binding("escape", "clear_filter", "Clear filter", show=False),
        Binding("q", "app.quit", "Quit"),
    ]

    def __init__(self, source: FleetSource, *, refresh_s: float = 0.25,
                 redraw_s: float = 0.0, farm: FarmRows | None = None) -> None:
        super().__init__()
        self.source = source
        self.farm = farm  # the farm queue's rows, shown under the table when given
        self.model = FleetModel()
        self.query_text = ""
        self.refresh_s = max(refresh_s, redraw_s)
        self.redraw_s = redraw_s  # > 0 (a slow link): also the opened printer's screen
        self.note = ""
        self.collect_stamps = False  # True: rows_shown() gets each shown status' timestamp
        self._shown: dict[str, tuple[str, ...]] = {}
        self._header_width = 0
        self._texts: dict[str, str] = {}
        self.opened: PrinterScreen | None = None  # the printer's screen pushed over this one

    def compose(self) -> ComposeResult:
        yield Static("waiting for printers...", id="counts")
        yield Input(placeholder="filter by name, job or state; Enter keeps it, Esc clears",
                    id="filter")
        yield Static("", id="columns")
        yield FleetTable(id="fleet")
        if self.farm is not None:
            yield FarmPanel(self.farm, id="farm")
        yield Static("", id="note")
        yield Footer()

    @property
    def table(self) -> FleetTable:
        return self.query_one("#fleet", FleetTable)

    def on_mount(self) -> None:
        self.sub_title = self.source.label
        self.set_interval(self.refresh_s, self.flush)
        self.run_worker(self._pump(), name="fleet-pump", exclusive=True)
        self.table.focus()

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
            opened = self.opened
            if opened is not None and item.printer == opened.printer:
                self._forward(opened, item)

    def _forward(self, opened: PrinterScreen, item: Any) -> None:
        """Pass one item of the open printer to its screen (a last will as an offline status)."""
        if opened not in self.app.screen_stack:
            self._replies(opened.printer, False)
            self.opened = None
            return
        if isinstance(item, AvailabilityItem):
            snap = shown_snapshot(self.model.entries[item.printer])
            if item.online or snap is None:
                return
            item = StatusItem(item.printer, snap)
        opened.feed(item)

    async def open_printer(self, printer: str) -> None:
        """Push the printer's own screen, showing at once the last status heard from it."""
        screen = PrinterScreen(self.source, printer, own_stream=False, back=True,
                               redraw_s=self.redraw_s)
        self.opened = screen
        self._replies(printer, True)  # its requests' replies, while the screen is open
        await self.app.push_screen(screen)
        entry = self.model.entries.get(printer)
        snap = shown_snapshot(entry) if entry is not None else None
        if snap is not None:
            screen.feed(StatusItem(printer, snap))

    def on_screen_resume(self) -> None:
        if self.opened is not None:  # back from the printer's screen
            self._replies(self.opened.printer, False)
        self.opened = None

    def _replies(self, printer: str, follow: bool) -> None:
        """Follow (or stop following) the replies of ``printer`` to this view's requests."""
        method = getattr(self.source, "open_replies" if follow else "close_replies", None)
        if method is not None:
            method(printer)

    def _event(self, item: EventItem) -> None:
        event = item.event
        if event.get("event") != "error":
            return
        stamp = time.strftime("%H:%M:%S", time.localtime(float(event.get("ts") or time.time())))
        cmd = event.get("cmd") or "command"
        self.note = f"{stamp} [b]{item.printer}[/b] refused {cmd}: [red]{event.get('reason')}[/]"

    def flush(self) -> None:
        """Apply the changes since the last flush to the table and the counts."""
        self._set_text("#note", self.note)
        table = self.table
        if table.row_width != self._header_width:
            self._header_width = table.row_width
            self._set_text("#columns", header_text(table.row_width))
        dirty = self.model.take_dirty()
        if not dirty:
            return
        model, query, shown = self.model, self.query_text, self._shown
        stamps: list[float] = []
        reorder = False
        for printer in dirty:
            entry = model.entries[printer]
            cells = row_cells(printer, entry)
            old = shown.get(printer)
            if query and not matches(printer, entry, query):
                if old is not None:
                    del shown[printer]
                    reorder = True
                continue
            if entry.snapshot is not None:
                stamps.append(entry.snapshot.ts)
            if old is None or old[1] != cells[1]:
                reorder = True
            if old != cells:
                shown[printer] = cells
                table.update_row(printer, cells)
        if reorder:
            table.set_rows(sorted(shown, key=model.sort_key), shown)
        self._show_counts()
        if self.collect_stamps and stamps:
            self.call_after_refresh(self.rows_shown, stamps)

    def rows_shown(self, stamps: list[float]) -> None:
        """Called after the screen shows statuses stamped ``stamps`` (for measurements)."""

    def cursor_printer(self) -> str | None:
        """The id of the printer under the cursor, if any."""
        return self.table.cursor_printer()

    def _show_counts(self) -> None:
        counts = self.model.counts()
        total = len(self.model.entries)
        parts = [f"[b]{total}[/b] printers on {self.source.label}"]
        if self.query_text:
            parts[0] += f" ([b]{len(self._shown)}[/b] shown for '{self.query_text}')"
        for state in COUNTED:
            if counts[state] or state in ("error", "offline", "printing", "idle"):
                parts.append(f"[{STYLES[state]}]{state}[/] {counts[state]}")
        self._set_text("#counts", "  ".join(parts))

    def _set_text(self, selector: str, text: str) -> None:
        """Update a one-line Static only when its text changes (an update lays out again)."""
        if self._texts.get(selector) != text:
            self._texts[selector] = text
            self.query_one(selector, Static).update(text)

    def rebuild(self) -> None:
        """Refill the table from the model (after the filter changed)."""
        model = self.model
        model.take_dirty()
        order = model.ordered(self.query_text)
        self._shown = {printer: row_cells(printer, model.entries[printer]) for printer in order}
        self.table.set_rows(order, self._shown)
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

    async def on_fleet_table_chosen(self, message: FleetTable.Chosen) -> None:
        await self.open_printer(message.printer)


class FleetApp(App[None]):
    """``hostd tui --mqtt``: the fleet table; Enter opens one printer's dashboard over MQTT."""

    TITLE = "hostd fleet"
    ENABLE_COMMAND_PALETTE = False  # its ctrl+p key would crowd the footer out

    def __init__(self, source: FleetSource, *, refresh_s: float = 0.25,
                 redraw_s: float | None = None, farm: FarmRows | None = None) -> None:
        super().__init__()
        partial_output.install()
        self.source = source
        self.farm = farm
        self.refresh_s = refresh_s
        self.redraw_s = redraw_seconds() if redraw_s is None else redraw_s

    def fleet_screen(self) -> FleetScreen:
        """The fleet screen this app opens on."""
        return FleetScreen(self.source, refresh_s=self.refresh_s, redraw_s=self.redraw_s,
                           farm=self.farm)

    def on_mount(self) -> None:
        self.push_screen(self.fleet_screen())
