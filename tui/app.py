"""The Textual dashboard of one printer over its daemon's control socket."""

from __future__ import annotations

import os

from textual.app import App

from tui import partial_output
from tui.printer_screen import PrinterScreen
from tui.sources import Source

REDRAW_ENV = "HOSTD_TUI_REDRAW_S"


def redraw_seconds(value: str | None = None) -> float:
    """The slow-link setting: ``value``, else ``$HOSTD_TUI_REDRAW_S``, else 0 (off).

    Raises ValueError for anything but a number of seconds >= 0.
    """
    text = os.environ.get(REDRAW_ENV, "") if value is None else value
    if not text.strip():
        return 0.0
    seconds = float(text)
    if not seconds >= 0 or seconds == float("inf"):
        raise ValueError(f"{text!r} is not a number of seconds >= 0")
    return seconds


class Dashboard(App[None]):
    """Opens :class:`PrinterScreen` on ``source``; ``q`` quits the dashboard, never the print."""

    TITLE = "hostd"
    ENABLE_COMMAND_PALETTE = False

    def __init__(self, source: Source, printer: str = "", redraw_s: float | None = None) -> None:
        super().__init__()
        partial_output.install()
        self.source = source
        self.printer = printer
        self.redraw_s = redraw_seconds() if redraw_s is None else redraw_s

    def on_mount(self) -> None:
        self.push_screen(PrinterScreen(self.source, self.printer, redraw_s=self.redraw_s))

    @property
    def printer_screen(self) -> PrinterScreen:
        """The printer's screen (the bottom pushed screen)."""
        return next(s for s in self.screen_stack if isinstance(s, PrinterScreen))
