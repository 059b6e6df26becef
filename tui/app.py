"""The Textual dashboard: job, progress, temperatures, queue and log, with pause/resume/cancel."""

from __future__ import annotations

import time
from typing import Any, ClassVar

from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.message import Message
from textual.widgets import Footer, Header, ProgressBar, RichLog, Static

from hostd.api import ControlError, Snapshot
from tui.sources import EventItem, Source, StatusItem


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "--"
    seconds = int(max(seconds, 0))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


def describe_job(snapshot: Snapshot) -> str:
    """The job panel's text for a snapshot."""
    job = snapshot.job
    if job is None:
        return "No job. Drop an STL into the job folder."
    return (
        f"[b]{job.name}[/b]  (job {job.id})\n"
        f"layer {job.layer}/{job.layers}   lines acknowledged {job.lines_acked}\n"
        f"elapsed {_duration(job.elapsed_s)}   ETA {_duration(job.eta_s)}   "
        f"layers ready ahead {job.layers_ready_ahead}"
    )


def describe_temps(snapshot: Snapshot) -> str:
    """The temperature panel's text for a snapshot."""
    hot, bed = snapshot.temps.hotend, snapshot.temps.bed
    return (
        f"hotend {hot.actual:6.1f} / {hot.target:5.1f} °C\n"
        f"bed    {bed.actual:6.1f} / {bed.target:5.1f} °C"
    )


def describe_queue(snapshot: Snapshot) -> str:
    """The queue panel's text: queued names and resumable interrupted jobs."""
    lines = [f"{n + 1}. {name}" for n, name in enumerate(snapshot.queue)] or ["(empty)"]
    if snapshot.interrupted:
        lines.append("")
        lines.append("[b]interrupted[/b] (resume with R):")
        lines += [
            f"  {job.name} (job {job.id}) at layer {job.layer}" for job in snapshot.interrupted
        ]
    return "\n".join(lines)


class StatusChanged(Message):
    """A new snapshot arrived for a printer."""

    def __init__(self, item: StatusItem) -> None:
        super().__init__()
        self.item = item


class EventArrived(Message):
    """A job event arrived."""

    def __init__(self, item: EventItem) -> None:
        super().__init__()
        self.item = item


class Dashboard(App[None]):
    """One printer's (or the selected fleet printer's) live status, with control keys."""

    TITLE = "hostd"
    CSS = """
    #top { height: auto; }
    .panel { border: round $accent; padding: 0 1; height: auto; }
    #job { width: 2fr; }
    #temps { width: 1fr; }
    #progress { margin: 0 1; }
    #bottom { height: 1fr; }
    #queue { width: 1fr; height: 1fr; }
    #log { width: 2fr; border: round $accent; }
    """
    BINDINGS: ClassVar[list[Binding]] = [
        Binding("p", "command('pause')", "Pause"),
        Binding("r", "command('resume')", "Resume"),
        Binding("c", "cancel", "Cancel (twice)"),
        Binding("R", "resume_job", "Resume interrupted"),
        Binding("n", "next_printer", "Next printer"),
        Binding("q", "quit", "Quit"),
    ]

    def __init__(self, source: Source) -> None:
        super().__init__()
        self.source = source
        self.snapshots: dict[str, Snapshot] = {}
        self.selected = ""
        self._cancel_armed_at = 0.0

    def compose(self) -> ComposeResult:
        yield Header(show_clock=True)
        with Horizontal(id="top"):
            yield Static("connecting...", id="job", classes="panel")
            yield Static("", id="temps", classes="panel")
        yield ProgressBar(total=1.0, id="progress", show_eta=False)
        with Horizontal(id="bottom"):
            with Vertical(id="queue", classes="panel"):
                yield Static("", id="queue_text")
            yield RichLog(id="log", markup=True, wrap=True)
        yield Footer()

    def on_mount(self) -> None:
        self.sub_title = self.source.label
        self.run_worker(self._pump(), name="status-pump", exclusive=True)

    async def _pump(self) -> None:
        async for item in self.source.stream():
            if isinstance(item, StatusItem):
                self.post_message(StatusChanged(item))
            else:
                self.post_message(EventArrived(item))

    def on_status_changed(self, message: StatusChanged) -> None:
        item = message.item
        key = item.printer or self.selected
        self.snapshots[key] = item.snapshot
        if not self.selected or key == self.selected:
            self.selected = key
            self.show(item.snapshot)

    def on_event_arrived(self, message: EventArrived) -> None:
        event = message.item.event
        kind = event.get("event", "?")
        stamp = time.strftime("%H:%M:%S", time.localtime(event.get("ts", time.time())))
        details = " ".join(f"{k}={v}" for k, v in event.items() if k not in ("event", "ts"))
        colour = {"failed": "red", "error": "red", "done": "green"}.get(kind, "cyan")
        who = f"{message.item.printer} " if message.item.printer else ""
        self.query_one("#log", RichLog).write(f"{stamp} {who}[{colour}]{kind}[/] {details}")

    def show(self, snapshot: Snapshot) -> None:
        """Render one snapshot into the panels."""
        connected = "connected" if snapshot.printer.connected else "not connected"
        self.title = f"hostd · {snapshot.printer.id} · {snapshot.state.upper()} · {connected}"
        job_text = describe_job(snapshot)
        if snapshot.error:
            job_text += f"\n[red]error: {snapshot.error}[/red]"
        self.query_one("#job", Static).update(job_text)
        self.query_one("#temps", Static).update(describe_temps(snapshot))
        self.query_one("#queue_text", Static).update(describe_queue(snapshot))
        progress = snapshot.job.progress if snapshot.job else 0.0
        self.query_one("#progress", ProgressBar).update(progress=progress)

    async def _send(self, cmd: str, **args: Any) -> None:
        try:
            await self.source.command(self.selected, cmd, **args)
            self.query_one("#log", RichLog).write(f"[b]> {cmd}[/b] sent")
        except (ControlError, OSError) as exc:
            self.query_one("#log", RichLog).write(f"[red]> {cmd} refused: {exc}[/red]")

    async def action_command(self, cmd: str) -> None:
        await self._send(cmd)

    async def action_cancel(self) -> None:
        now = time.monotonic()
        if now - self._cancel_armed_at < 3.0:
            self._cancel_armed_at = 0.0
            await self._send("cancel")
        else:
            self._cancel_armed_at = now
            self.query_one("#log", RichLog).write("[yellow]press c again within 3 s to cancel[/]")

    async def action_resume_job(self) -> None:
        snapshot = self.snapshots.get(self.selected)
        if snapshot is None or not snapshot.interrupted:
            self.query_one("#log", RichLog).write("no interrupted job to resume")
            return
        await self._send("resume_job", job=snapshot.interrupted[0].id)

    def action_next_printer(self) -> None:
        names = sorted(self.snapshots)
        if len(names) > 1:
            self.selected = names[(names.index(self.selected) + 1) % len(names)]
            self.show(self.snapshots[self.selected])
