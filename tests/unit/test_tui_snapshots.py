"""Snapshots of the single-printer dashboard and its help, fed a fixed story (deterministic)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from support.tui_helpers import FixedSource
from support.waiting import until

from tui.app import Dashboard
from tui.widgets.dialogs import HelpScreen
from tui.widgets.layer import LayerView


@pytest.fixture(autouse=True)
def utc(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Event times drawn in UTC whatever the machine's zone."""
    monkeypatch.setenv("TZ", "UTC")
    time.tzset()
    yield
    monkeypatch.undo()
    time.tzset()


async def settled(pilot) -> None:
    """Wait until the story is told: every event, the layer, its progress and the estimate."""
    screen = pilot.app.printer_screen
    await until(lambda: len(screen.events) == 13 and screen.layer_data is not None
                and screen.query_one(LayerView).printed is not None
                and screen.estimate is not None)
    await pilot.pause()


def test_dashboard_80x24(snap_compare) -> None:
    assert snap_compare(Dashboard(FixedSource()), terminal_size=(80, 24), run_before=settled)


def test_dashboard_200x60(snap_compare) -> None:
    assert snap_compare(Dashboard(FixedSource()), terminal_size=(200, 60), run_before=settled)


def test_dashboard_field_overlay_120x40(snap_compare) -> None:
    async def field(pilot) -> None:
        await settled(pilot)
        await pilot.press("f")
        view = pilot.app.printer_screen.query_one(LayerView)
        await until(lambda: view.data is not None and view.data.get("field") is not None)
        await pilot.pause()

    assert snap_compare(Dashboard(FixedSource()), terminal_size=(120, 40), run_before=field)


def test_help_80x24(snap_compare) -> None:
    async def help_open(pilot) -> None:
        await settled(pilot)
        await pilot.press("question_mark")
        await until(lambda: isinstance(pilot.app.screen, HelpScreen))
        await pilot.pause()

    assert snap_compare(Dashboard(FixedSource()), terminal_size=(80, 24), run_before=help_open)
