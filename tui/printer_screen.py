"""One printer's dashboard as a Textual screen, fed by any ``Source`` (control socket or MQTT).

``PrinterScreen(source, printer)`` reads ``source.stream()`` itself (``own_stream``)
or is fed by its owner through :meth:`PrinterScreen.feed` (a fleet view that
already reads the broker). The layer picture and the estimates use
``source.query`` (the control socket, or requests over MQTT); a source that
cannot answer gets a note instead.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any, ClassVar

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import Screen
from textual.widgets import Footer

from hostd.api import ControlError, Snapshot
from tui.format import describe_event, layer_text
from tui.sources import EventItem, Source, StatusItem
from tui.widgets.dialogs import (
    ConfirmScreen,
    FilterScreen,
    HelpScreen,
    ObjectsScreen,
    RetuneScreen,
    retune_question,
)
from tui.widgets.eventlog import EventLog
from tui.widgets.layer import PROGRESS_S, LayerView
from tui.widgets.panels import JobPanel, QueuePanel, StateBar, TempPanel

NO_LAYER_VIEW = "the layer picture needs the daemon's control socket (hostd tui --socket)"
LOG_LINES = 500
RETRY_S = 5.0


class PrinterScreen(Screen[None]):
    """State, job, temperatures, queue, event log and the current layer of one printer."""

    CSS = """
    PrinterScreen { layout: vertical; }
    #state { height: 1; background: $boost; }
    #body { height: 1fr; }
    #left { width: 1fr; min-width: 38; max-width: 76; }
    .panel { border: round $primary; padding: 0 1; }
    #job { height: 6; }
    #temps { height: 1fr; min-height: 5; max-height: 16; }
    #queue { height: auto; max-height: 6; }
    #log { height: 1fr; min-height: 4; border: round $primary; scrollbar-size-vertical: 1; }
    #layer { width: 1fr; height: 1fr; border: round $primary; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("p", "command('pause')", "Pause"),
        Binding("r", "command('resume')", "Resume"),
        Binding("c", "cancel", "Cancel"),
        Binding("o", "objects", "Parts"),
        Binding("t", "retune", "Tune"),
        Binding("f", "field", "Field"),
        Binding("slash", "filter", "Filter", key_display="/"),
        Binding("question_mark", "help", "Help", key_display="?"),
        Binding("exclamation_mark", "emergency_stop", "E-stop", key_display="!"),
        Binding("q", "leave", "Quit"),
        Binding("escape,q", "back", "Back", key_display="q"),
        Binding("R", "resume_job", "Resume interrupted", show=False),
    ]

    def __init__(self, source: Source, printer: str = "", own_stream: bool = True,
                 back: bool = False, redraw_s: float = 0.0) -> None:
        super().__init__()
        self.redraw_s = redraw_s  # > 0 (a slow link): picture and log at most this often
        self.source = source
        self.printer = printer
        self.own_stream = own_stream
        self.back = back  # q and Escape go back to the screen below instead of quitting
        self.snapshot = Snapshot(state="offline", error="connecting...")
        self.layer_data: dict[str, Any] | None = None
        self.estimate: dict[str, Any] | None = None
        self.events: list[tuple[float, str, str]] = []
        self.log_filter = ""
        self._layer_key: tuple[str, int, bool] | None = None
        self._estimated_at: tuple[str, int] | None = None
        self._retry_at = 0.0  # when a layer that could not be fetched is asked for again
        self._layer_failed = False
        self._early: list[StatusItem | EventItem] = []  # fed before the screen was mounted

    def compose(self) -> ComposeResult:
        yield StateBar(id="state")
        with Horizontal(id="body"):
            with Vertical(id="left"):
                yield JobPanel(id="job", classes="panel")
                yield TempPanel(id="temps", classes="panel")
                yield QueuePanel(id="queue", classes="panel")
                yield EventLog(LOG_LINES, id="log", batch_s=self.redraw_s)
            yield LayerView(id="layer", progress_s=max(PROGRESS_S, self.redraw_s),
                            layer_s=self.redraw_s)
        yield Footer(compact=True)

    def on_mount(self) -> None:
        titles = {"#job": "job", "#temps": "temperatures · last 10 min", "#queue": "queue",
                  "#log": "events", "#layer": "layer"}
        for selector, title in titles.items():
            self.query_one(selector).border_title = title
        early, self._early = self._early, []
        for item in early:
            self.feed(item)
        if self.own_stream:
            self.run_worker(self._pump, name="status-pump", exclusive=True)

    async def _pump(self) -> None:
        async for item in self.source.stream():
            self.feed(item)

    # -- incoming -------------------------------------------------------------

    def feed(self, item: StatusItem | EventItem) -> None:
        """One status snapshot or event from the source (others' printers are ignored)."""
        if self.printer and item.printer and item.printer != self.printer:
            return
        if not self.printer and item.printer and isinstance(item, StatusItem):
            self.printer = item.printer  # the first printer heard from is the one shown
        if not self.is_mounted:  # fed (by the fleet) before its widgets exist: shown on mount
            self._early.append(item)
            return
        if isinstance(item, StatusItem):
            self.show(item.snapshot)
        else:
            self.add_event(item.event)

    def show(self, snapshot: Snapshot) -> None:
        """Render one snapshot and fetch the layer or estimate it makes stale."""
        self.snapshot = snapshot
        self.query_one(StateBar).show(snapshot, self.source.label)
        self.query_one(JobPanel).show(snapshot)
        self.query_one(TempPanel).show(snapshot)
        self.query_one(QueuePanel).show(snapshot)
        self._follow_layer()
        self._follow_estimate()

    def add_event(self, event: dict[str, Any]) -> None:
        """Append one job event to the log (kept for the filter)."""
        colour, text = describe_event(event)
        self._append(float(event.get("ts", 0.0)), colour, text)
        if event.get("event") in ("object_cancelled", "object_restored"):
            self._layer_key = None  # the picture's list of cancelled bodies changed

    def _append(self, ts: float, colour: str, text: str) -> None:
        self.events.append((ts, colour, text))
        del self.events[:-LOG_LINES]
        if self.log_filter.lower() in text.lower():
            self.query_one(EventLog).add(self.events[-1])

    def note(self, text: str, colour: str = "white") -> None:
        """A line of the dashboard's own in the log (command sent, refused...)."""
        self._append(self.snapshot.ts or 0.0, colour, text)

    # -- the layer picture ----------------------------------------------------

    def _follow_layer(self) -> None:
        view = self.query_one(LayerView)
        job = self.snapshot.job
        if job is None or not job.layers:
            self.layer_data, self._layer_key = None, None
            view.show(None, "no job printing" if job is None else "slicing...")
            return
        key = (job.id, job.layer, view.show_field)
        retry = self._layer_failed and time.monotonic() > self._retry_at
        if key != self._layer_key or retry:
            self._layer_key = key
            self._retry_at = time.monotonic() + RETRY_S
            self.run_worker(partial(self._load_layer, job.layer), group="layer", exclusive=True)
        self._show_progress()

    def _show_progress(self) -> None:
        view, job, data = self.query_one(LayerView), self.snapshot.job, self.layer_data
        if job is None or data is None or data.get("job") not in (None, job.id):
            return
        if data["layer"] < job.layer or self.snapshot.state == "idle":
            view.progress(data["commands"])
        elif data["layer"] == job.layer and data.get("acked_before") is not None:
            view.progress(max(0, job.lines_acked - data["acked_before"]))
        else:
            view.progress(None)

    async def _load_layer(self, index: int) -> None:
        view = self.query_one(LayerView)
        args: dict[str, Any] = {"layer": index}
        width, height = view.content_size.width, max(1, view.content_size.height - 1)
        if self.layer_data is not None:
            xmin, ymin, xmax, ymax = self.layer_data["bounds"]
            mm_per_dot = max((xmax - xmin) / (2 * width), (ymax - ymin) / (4 * height), 0.01)
            args["tolerance"] = round(min(mm_per_dot * 0.5, 5.0), 3)
        if view.show_field:
            args["field"] = [max(1, width), max(1, height)]
        try:
            data = await self._query("layer", **args)
        except ControlError as exc:
            self.layer_data, self._layer_failed = None, True
            view.show(None, str(exc))
            return
        self._layer_failed = False
        self.layer_data = data
        view.show(data)
        self._show_progress()

    async def _query(self, cmd: str, **args: Any) -> dict[str, Any]:
        query = getattr(self.source, "query", None)
        if query is None:
            raise ControlError(NO_LAYER_VIEW)
        return await query(self.printer, cmd, **args)

    # -- filament estimate ----------------------------------------------------

    def _follow_estimate(self) -> None:
        job = self.snapshot.job
        if job is None or not job.layers or job.filament_total_mm is not None:
            return  # the status carries the daemon's own filament figures
        step = max(1, job.layers // 10)
        last = self._estimated_at
        if last is None or last[0] != job.id or job.layer - last[1] >= step:
            self._estimated_at = (job.id, job.layer)
            self.run_worker(self._load_estimate, group="estimate", exclusive=True)

    async def _load_estimate(self) -> None:
        try:
            self.estimate = await self._query("estimate")
        except ControlError:
            return
        if not self.is_mounted:  # the screen was closed meanwhile
            return
        used = self.estimate.get("filament_used_mm")
        total = self.estimate.get("filament_total_mm")
        panel = self.query_one(JobPanel)
        panel.filament = (used, total) if used is not None and total is not None else None
        panel.refresh()

    # -- keys -----------------------------------------------------------------

    async def _send(self, cmd: str, **args: Any) -> bool:
        try:
            await self.source.command(self.printer, cmd, **args)
        except (ControlError, OSError) as exc:
            self.note(f"{cmd} refused: {exc}", "red")
            return False
        self.note(f"> {cmd} {' '.join(f'{k}={v}' for k, v in args.items())}".rstrip(), "bold")
        return True

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """``q`` quits, or with ``back`` (over the fleet) goes back, as its footer label says."""
        if action == "leave":
            return not self.back
        if action == "back":
            return self.back
        return True

    async def action_command(self, cmd: str) -> None:
        await self._send(cmd)

    def action_emergency_stop(self) -> None:
        question = ("[b red]Emergency stop?[/]\n"
                    f"M112 halts {self.printer or 'the printer'} at once, heaters off.\n"
                    "The job fails; the printer needs a reset (or power cycle).")

        async def answered(yes: bool | None) -> None:
            if yes:
                await self._send("emergency_stop")

        self.app.push_screen(ConfirmScreen(question), answered)

    def action_cancel(self) -> None:
        job = self.snapshot.job
        if job is None:
            self.note("no job to cancel", "yellow")
            return
        question = (f"Cancel [b]{job.name}[/b] at {layer_text(job.layer, job.layers)}?\n"
                    "The part stays unfinished on the bed.")

        async def answered(yes: bool | None) -> None:
            if yes:
                await self._send("cancel")

        self.app.push_screen(ConfirmScreen(question), answered)

    async def action_resume_job(self) -> None:
        if not self.snapshot.interrupted:
            self.note("no interrupted job to resume", "yellow")
            return
        await self._send("resume_job", job=self.snapshot.interrupted[0].id)

    def action_objects(self) -> None:
        data = self.layer_data
        if data is None:
            self.note("no layer to show the bodies of", "yellow")
            return
        if data["body_count"] < 2:
            self.note("one body on the plate: cancel the job instead", "yellow")
            return
        view = self.query_one(LayerView)

        def highlight(body: int | None) -> None:
            view.highlight = body
            view.redraw_now()

        async def chosen(choice: tuple[str, int] | None) -> None:
            highlight(None)
            if choice is None:
                return
            what, body = choice
            cmd = "cancel_object" if what == "cancel" else "restore_object"
            if await self._send(cmd, object=body):
                self._layer_key = None
                self._estimated_at = None
                self._follow_layer()

        self.app.push_screen(ObjectsScreen(data, highlight), chosen)

    async def action_retune(self) -> None:
        try:
            now = await self._query("estimate")
        except ControlError as exc:
            self.note(f"retune unavailable: {exc}", "red")
            return

        async def confirmed(yes: bool | None, changes: dict[str, Any]) -> None:
            if yes and await self._send("set", settings=changes):
                self._estimated_at = None

        async def edited(changes: dict[str, Any] | None) -> None:
            if not changes:
                return
            try:
                reply = await self._query("estimate", settings=changes)
            except ControlError as exc:
                self.note(f"retune refused: {exc}", "red")
                return
            self.app.push_screen(ConfirmScreen(retune_question(changes, reply)),
                                 lambda yes: confirmed(yes, changes))

        self.app.push_screen(RetuneScreen(now["settings"], now["fields"]), edited)

    def action_field(self) -> None:
        view = self.query_one(LayerView)
        view.show_field = not view.show_field
        view.redraw_now()
        if self.layer_data is not None and self.layer_data.get("field") is None and view.show_field:
            self._layer_key = None
        self._follow_layer()

    def action_filter(self) -> None:
        def chosen(text: str | None) -> None:
            if text is None:
                return
            self.log_filter = text
            log = self.query_one(EventLog)
            log.border_title = f"events · filter {text!r}" if text else "events"
            log.show(entry for entry in self.events if text.lower() in entry[2].lower())

        self.app.push_screen(FilterScreen(self.log_filter), chosen)

    def action_help(self) -> None:
        self.app.push_screen(HelpScreen())

    def action_leave(self) -> None:
        """Quit the dashboard; never the print."""
        self.app.exit()

    def action_back(self) -> None:
        """Back to the screen below (the fleet)."""
        self.app.pop_screen()
