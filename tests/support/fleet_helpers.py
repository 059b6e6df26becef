"""What the fleet tests share: the repository folder and the fleet table's rows."""

from __future__ import annotations

from pathlib import Path

from tui.fleet import FleetApp
from tui.fleet_table import FleetTable

REPO = Path(__file__).resolve().parents[2]


def rows(app: FleetApp) -> list[tuple[str, str]]:
    """(printer, state) of every row, top to bottom."""
    table = app.screen.query_one("#fleet", FleetTable)
    return [table.row_at(i)[:2] for i in range(table.row_count)]
