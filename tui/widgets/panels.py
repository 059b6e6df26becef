"""The text panels of one printer: state line, job, temperatures with a chart, queue."""

from __future__ import annotations

from collections import deque

import numpy as np
from rich.style import Style
from rich.text import Text

from hostd.api import Snapshot, bar, duration
from tui.canvas import Canvas
from tui.format import layer_text, metres
from tui.widgets.lines import LinesWidget

STATE_COLOURS = {
    "printing": "green", "heating": "yellow", "paused": "yellow", "idle": "cyan",
    "error": "red", "offline": "red",
}
HISTORY_S = 600.0  # the temperature chart's span: the last 10 minutes
HOTEND, BED = Style(color="#ff6e4a"), Style(color="#4aa8ff")


def line(*parts: str | tuple[str, str]) -> Text:
    """One line that never wraps: cut with an ellipsis when too long."""
    return Text.assemble(*parts, no_wrap=True, overflow="ellipsis")


class StateBar(LinesWidget):
    """The top line: printer, state, connection, and the error if any."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.snapshot = Snapshot(state="offline", error="connecting...")
        self.label = ""

    def show(self, snapshot: Snapshot, label: str) -> None:
        self.snapshot, self.label = snapshot, label
        self.redraw()

    def content_lines(self, width: int, height: int) -> list[Text]:
        return [self.line()]

    def line(self) -> Text:
        """The state line."""
        snap = self.snapshot
        colour = STATE_COLOURS.get(snap.state, "white")
        link = ("connected", "green") if snap.printer.connected else ("not connected", "red")
        parts: list[str | tuple[str, str]] = [
            (" hostd ", "bold"), f"{snap.printer.id}  ",
            (f" {snap.state.upper()} ", f"bold black on {colour}"), "  ", link,
        ]
        if snap.error:
            parts += ["  ", (snap.error, "bold red")]
        elif self.label:
            parts += [("  " + self.label, "dim")]
        return line(*parts)


class JobPanel(LinesWidget):
    """Name, layer N of M with a bar, elapsed and ETA, filament used of total, layers ahead."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.snapshot = Snapshot()
        # used, total mm (an `estimate`), for a status without the daemon's own figures
        self.filament: tuple[float, float] | None = None

    def show(self, snapshot: Snapshot) -> None:
        self.snapshot = snapshot
        self.redraw()

    def content_lines(self, width: int, height: int) -> list[Text]:
        job = self.snapshot.job
        if job is None:
            waiting = f"{len(self.snapshot.queue)} queued" if self.snapshot.queue else "no job"
            return [line((waiting, "bold")), line(("drop an STL into the job folder", "dim"))]
        layer = layer_text(job.layer, job.layers) if job.layers else "starting"
        pct = f" {job.progress * 100:3.0f}%"
        bar_width = max(4, width - len(layer) - len(pct) - 2)
        used, total = self.filament if self.filament else (None, None)
        if job.filament_total_mm is not None:  # the daemon's own figures, in every status
            used, total = job.filament_used_mm, job.filament_total_mm
        return [
            line((job.name, "bold"), (f"  job {job.id}", "dim")),
            line(layer, "  ", (bar(job.progress, bar_width), "green"), pct),
            line("elapsed ", (duration(job.elapsed_s), "bold"), "  ETA ",
                 (duration(job.eta_s), "bold"), "  ahead ", (str(job.layers_ready_ahead), "bold"),
                 (f"  waiting for the {job.waiting_for}" if job.waiting_for else "", "yellow")),
            line("filament ", ("≈" if total else "", "dim"),
                 (metres(used).removesuffix(" m"), "bold"), " of ", (metres(total), "bold")),
        ]


class TempPanel(LinesWidget):
    """Hotend and bed, actual / target, and a braille chart of the last 10 minutes."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.snapshot = Snapshot()
        self.history: deque[tuple[float, float, float]] = deque()  # ts, hotend, bed

    def show(self, snapshot: Snapshot) -> None:
        self.snapshot = snapshot
        temps = snapshot.temps
        if not self.history or snapshot.ts > self.history[-1][0]:
            self.history.append((snapshot.ts, temps.hotend.actual, temps.bed.actual))
        while self.history and self.history[0][0] < snapshot.ts - HISTORY_S:
            self.history.popleft()
        self.redraw()

    def content_lines(self, width: int, height: int) -> list[Text]:
        hot, bed = self.snapshot.temps.hotend, self.snapshot.temps.bed
        head = line(("hotend ", HOTEND), (f"{hot.actual:.1f}", "bold"), f"/{hot.target:.0f}°C  ",
                    ("bed ", BED), (f"{bed.actual:.1f}", "bold"), f"/{bed.target:.0f}°C")
        rows = max(0, height - 1)
        if rows == 0:
            return [head]
        return [head, *self.chart_lines(width, rows)]

    def chart_lines(self, cols: int, rows: int) -> list[Text]:
        """Both heaters over the last 10 minutes (right edge = newest), 0 at the bottom.

        Time goes in steps of one dot column, counted from the epoch, so the curves
        move left a whole dot at a time: between two steps only the newest column
        can change (and only the rows it crosses are sent to the terminal).
        """
        canvas = Canvas(cols, rows)
        if self.history:
            data = np.asarray(self.history, dtype=float)
            temps = self.snapshot.temps
            top = max(50.0, float(data[:, 1:].max()), temps.hotend.target, temps.bed.target) * 1.05
            width, height = cols * 2, rows * 4
            step = HISTORY_S / max(1, width - 1)  # seconds per dot column
            slot = np.floor(data[:, 0] / step)
            x = width - 1 - (slot[-1] - slot)
            for column, colour in ((2, 1), (1, 0)):
                y = (height - 1) - data[:, column] / top * (height - 1)
                canvas.polylines([np.column_stack((x, y))], colour)
        return canvas.lines([HOTEND, BED])


class QueuePanel(LinesWidget):
    """Jobs waiting (never the one printing) and interrupted jobs."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.snapshot = Snapshot()

    def show(self, snapshot: Snapshot) -> None:
        rows = len(self.lines())
        self.snapshot = snapshot
        if len(self.lines()) != rows:  # the panel's height follows its lines
            self.refresh(layout=True)
        self.redraw()

    def get_content_height(self, container, viewport, width: int) -> int:
        return max(1, len(self.lines()))

    def lines(self) -> list[Text]:
        snap = self.snapshot
        out = [line((f"{n + 1}. ", "dim"), name) for n, name in enumerate(snap.queue)]
        if not out:
            out = [line(("queue empty", "dim"))]
        for job in snap.interrupted:
            after = f"after layer {job.layer + 1}" if job.layer >= 0 else "before layer 1"
            out.append(line(job.name, ("  stopped ", "yellow"), (after, "dim")))
        return out

    def content_lines(self, width: int, height: int) -> list[Text]:
        return self.lines()
