"""The farm queue beside the fleet table: failures first, then held, printing and waiting jobs."""

from __future__ import annotations

from collections import Counter
from collections.abc import Awaitable, Callable
from typing import Any

from rich.markup import escape
from textual.widgets import Static

# what gives the rows: `hostd farm list --json`'s objects (id, state, printer, reason, name)
FarmRows = Callable[[], Awaitable[list[dict[str, Any]]]]

ORDER = {"failed": 0, "interrupted": 1, "taken": 2, "waiting": 3, "printed": 4}
STYLES = {"failed": "bold red", "interrupted": "bold magenta", "taken": "green",
          "waiting": "yellow", "printed": "dim"}
SHOWN = {"taken": "printing"}  # a taken job is being printed


def farm_summary(rows: list[dict[str, Any]]) -> str:
    """``farm: 1 failed  2 printing  5 waiting  20 printed`` (markup)."""
    counts = Counter(str(row.get("state")) for row in rows)
    parts = ["[b]farm[/b]"]
    for state in ORDER:
        if counts[state] or state in ("waiting", "printed"):
            parts.append(f"[{STYLES[state]}]{SHOWN.get(state, state)}[/] {counts[state]}")
    return "  ".join(parts)


def farm_lines(rows: list[dict[str, Any]], limit: int = 8) -> list[str]:
    """One line (markup) per job not yet printed, failures first, at most ``limit``."""
    pending = sorted((row for row in rows if row.get("state") != "printed"),
                     key=lambda row: ORDER.get(str(row.get("state")), 5))
    lines = []
    for row in pending[:limit]:
        state = str(row.get("state"))
        where = f" on {row['printer']}" if row.get("printer") else ""
        why = f": {row['reason']}" if row.get("reason") else ""
        text = escape(f"{row.get('id')}  {row.get('name', '')}{where}{why}")
        lines.append(f"[{STYLES.get(state, '')}]{SHOWN.get(state, state):<11}[/] {text}")
    if len(pending) > limit:
        lines.append(f"[dim]... and {len(pending) - limit} more[/]")
    return lines


class FarmPanel(Static):
    """The farm queue's counts and its jobs not yet printed, read again every ``every_s``."""

    DEFAULT_CSS = """
    FarmPanel { height: auto; max-height: 10; padding: 0 1; border-top: solid $primary; }
    """

    def __init__(self, rows: FarmRows, every_s: float = 2.0, limit: int = 8,
                 **kwargs: Any) -> None:
        super().__init__("farm: reading the queue...", **kwargs)
        self.rows = rows
        self.every_s = every_s
        self.limit = limit
        self.text = ""

    def on_mount(self) -> None:
        self.run_worker(self._read(), exclusive=True, name="farm-queue")
        self.set_interval(self.every_s, self._again)

    def _again(self) -> None:
        self.run_worker(self._read(), exclusive=True, name="farm-queue")

    async def _read(self) -> None:
        try:
            rows = await self.rows()
        except Exception as exc:  # the queue out of reach: say so and try again
            self.show(f"[b]farm[/b]  [red]{escape(str(exc) or type(exc).__name__)}[/]")
            return
        self.show("\n".join([farm_summary(rows), *farm_lines(rows, self.limit)]))

    def show(self, text: str) -> None:
        """Show ``text`` (markup) if it changed."""
        if text != self.text:
            self.text = text
            self.update(text)
