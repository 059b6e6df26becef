"""The Textual dashboard of one printer over its daemon's control socket."""

from __future__ import annotations

from textual.app import App

from tui import partial_output
from tui.printer_screen import PrinterScreen
from tui.sources import Source


class Dashboard(App[None]):
    """Opens :class:`PrinterScreen` on ``source``; ``q`` quits the dashboard, never the print."""

    TITLE = "hostd"
    ENABLE_COMMAND_PALETTE = False

    def __init__(self, source: Source, printer: str = "") -> None:
        super().__init__()
        partial_output.install()
        self.source = source
        self.printer = printer

    def on_mount(self) -> None:
        self.push_screen(PrinterScreen(self.source, self.printer))

    @property
    def printer_screen(self) -> PrinterScreen:
        """The printer's screen (the bottom pushed screen)."""
        return next(s for s in self.screen_stack if isinstance(s, PrinterScreen))
