"""One printer of the fleet, opened from the fleet table and fed over MQTT."""

from __future__ import annotations

import time
from typing import Any, ClassVar

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.screen import Screen
from textual.widgets import Footer, ProgressBar, RichLog, Static

from hostd.api import ControlError, Snapshot
from tui.format import duration, layer_text
from tui.sources import EventItem, Source, StatusItem


def printer_screen(source: Source, printer_id: str) -> Screen[Any]:
    """The single-printer screen for ``printer_id`` fed by ``source`` (pushed over the fleet)."""
    return FleetPrinterScreen(source, printer_id)


def _job_text(snapshot: Snapshot) -> str:
    job = snapshot.job
    if job is None:
        return "no job"
    return (
        f"[b]{job.name}[/b] (job {job.id})\n"
        f"{layer_text(job.layer, job.layers)}\n"
        f"elapsed {duration(job.elapsed_s)}  ETA {duration(job.eta_s)}\n"
        f"layers sliced ahead {job.layers_ready_ahead}"
    )


def _temps_text(snapshot: Snapshot) -> str:
    hot, bed = snapshot.temps.hotend, snapshot.temps.bed
    return (f"hotend {hot.actual:5.1f}/{hot.target:3.0f}°C\n"
            f"bed    {bed.actual:5.1f}/{bed.target:3.0f}°C")


class FleetPrinterScreen(Screen[None]):
    """Status, job, temperatures, queue and events of one printer; keys send commands."""

    CSS = """
    #state { height: 1; padding: 0 1; background: $boost; }
    #panels { height: auto; }
    .panel { border: round $accent; padding: 0 1; height: auto; }
    #job { width: 1fr; }
    #temps { width: 24; }
    #bar { margin: 0 1; }
    #queue { height: auto; max-height: 6; }
    #events { height: 1fr; border: round $accent; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("p", "command('pause')", "Pause"),
        Binding("r", "command('resume')", "Resume"),
        Binding("c", "cancel", "Cancel (twice)"),
        Binding("escape", "app.pop_screen", "Fleet"),
        Binding("q", "app.quit", "Quit"),
    ]

    def __init__(self, source: Source, printer_id: str) -> None:
        super().__init__()
        self.source = source
        self.printer_id = printer_id
        self.snapshot: Snapshot | None = None
        self._cancel_armed_at = 0.0

    def compose(self) -> ComposeResult:
        yield Static(f"{self.printer_id}: waiting for its status...", id="state")
        with Horizontal(id="panels"):
            yield Static("", id="job", classes="panel")
            yield Static("", id="temps", classes="panel")
        yield ProgressBar(total=1.0, id="bar", show_eta=False)
        yield Static("", id="queue", classes="panel")
        yield RichLog(id="events", markup=True, wrap=True)
        yield Footer()

    def on_mount(self) -> None:
        self.run_worker(self._pump(), name=f"printer-{self.printer_id}", exclusive=True)

    async def _pump(self) -> None:
        async for item in self.source.stream():
            if isinstance(item, StatusItem) and item.printer == self.printer_id:
                self.show(item.snapshot)
            elif isinstance(item, EventItem) and item.printer == self.printer_id:
                self.log_event(item.event)

    def show(self, snapshot: Snapshot) -> None:
        """Render one status."""
        self.snapshot = snapshot
        state = snapshot.state.upper()
        link = "printer connected" if snapshot.printer.connected else "printer not connected"
        line = f"[b]{self.printer_id}[/b]  {state}  {link}"
        if snapshot.error:
            line += f"  [red]{snapshot.error}[/]"
        self.query_one("#state", Static).update(line)
        self.query_one("#job", Static).update(_job_text(snapshot))
        self.query_one("#temps", Static).update(_temps_text(snapshot))
        self.query_one("#bar", ProgressBar).update(
            progress=snapshot.job.progress if snapshot.job else 0.0)
        queue = ", ".join(snapshot.queue) or "(empty)"
        interrupted = ", ".join(f"{j.name} at layer {j.layer}" for j in snapshot.interrupted)
        self.query_one("#queue", Static).update(
            f"queue: {queue}" + (f"\ninterrupted: {interrupted}" if interrupted else ""))

    def log_event(self, event: dict[str, Any]) -> None:
        """One event line; a refused command in red with the printer's reason."""
        kind = str(event.get("event", "?"))
        stamp = time.strftime("%H:%M:%S", time.localtime(float(event.get("ts") or time.time())))
        if kind == "error":
            what = event.get("cmd") or "command"
            text = f"{stamp} [red]refused {what}: {event.get('reason')}[/]"
        else:
            details = " ".join(f"{k}={v}" for k, v in event.items() if k not in ("event", "ts"))
            text = f"{stamp} [cyan]{kind}[/] {details}"
        self.query_one("#events", RichLog).write(text)

    async def _send(self, cmd: str, **args: Any) -> None:
        log = self.query_one("#events", RichLog)
        try:
            await self.source.command(self.printer_id, cmd, **args)
        except (ControlError, OSError) as exc:
            log.write(f"[red]{cmd} not sent: {exc}[/]")
            return
        log.write(f"[b]> {cmd}[/b] sent")

    async def action_command(self, cmd: str) -> None:
        await self._send(cmd)

    async def action_cancel(self) -> None:
        now = time.monotonic()
        if now - self._cancel_armed_at < 3.0:
            self._cancel_armed_at = 0.0
            await self._send("cancel")
        else:
            self._cancel_armed_at = now
            self.query_one("#events", RichLog).write(
                "[yellow]press c again within 3 s to cancel the job[/]")
