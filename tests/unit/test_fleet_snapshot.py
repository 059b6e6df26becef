"""The fleet screen fed with fixed data, compared with its stored SVG (pytest-textual-snapshot)."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from typing import Any

from bench.fleetpub import snapshot
from hostd.api import ControlError
from tui.fleet import FleetApp
from tui.fleet_table import FleetTable
from tui.sources import AvailabilityItem, EventItem, StatusItem

NOW = 1_764_000_000.0
STATES = ("printing", "idle", "printing", "paused", "error", "printing", "heating", "printing")


class FixedFleet:
    """Twenty printers with set statuses, one lost (its last will), one refusal; then quiet."""

    label = "mqtt broker.farm:1883"

    def fleet_stream(self) -> AsyncIterator[StatusItem | EventItem | AvailabilityItem]:
        return self._items()

    async def _items(self) -> AsyncIterator[StatusItem | EventItem | AvailabilityItem]:
        for index in range(20):
            state = STATES[index % len(STATES)]
            yield StatusItem(f"farm-{index:02d}", snapshot(index, NOW, state, NOW - 3600))
        yield AvailabilityItem("farm-05", False)
        reason = "commands are disabled (mqtt.allow_commands = false)"
        yield EventItem("farm-03", {"event": "error", "cmd": "resume", "ts": NOW, "reason": reason})
        await asyncio.Event().wait()

    def stream(self) -> Any:
        raise NotImplementedError

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        raise ControlError("fixed data")



async def _loaded(pilot: Any) -> None:
    table = pilot.app.screen.query_one("#fleet", FleetTable)
    while table.row_count < 20:
        await pilot.pause(0.05)
    await pilot.pause(0.1)


def test_fleet_screen(snap_compare: Any, monkeypatch: Any) -> None:
    monkeypatch.setenv("TZ", "UTC")  # the refusal's time of day is shown
    time.tzset()
    try:
        assert snap_compare(FleetApp(FixedFleet(), refresh_s=0.05), terminal_size=(100, 26),
                            run_before=_loaded)
    finally:
        monkeypatch.undo()
        time.tzset()


def test_fleet_opens_the_printer_screen(snap_compare: Any) -> None:
    """Enter: the dashboard of the printer on top, from the statuses the fleet heard."""

    async def opened(pilot: Any) -> None:
        from support.waiting import until

        from tui.printer_screen import PrinterScreen

        await _loaded(pilot)
        await pilot.press("enter")
        await until(lambda: isinstance(pilot.app.screen, PrinterScreen))
        assert pilot.app.screen.printer == "farm-04"  # the first error sorts on top
        await pilot.pause(0.1)

    assert snap_compare(FleetApp(FixedFleet(), refresh_s=0.05), terminal_size=(80, 24),
                        run_before=opened)


class ThousandPrinters(FixedFleet):
    """A thousand printers, one status each, then quiet."""

    async def _items(self) -> AsyncIterator[StatusItem | EventItem | AvailabilityItem]:
        for index in range(1000):
            state = STATES[index % len(STATES)]
            yield StatusItem(f"p{index:04d}", snapshot(index, NOW, state, NOW - 3600))
        await asyncio.Event().wait()


def test_a_thousand_printers_scroll_and_filter_at_80x24() -> None:
    async def scenario() -> None:
        app = FleetApp(ThousandPrinters(), refresh_s=0.05)
        async with app.run_test(size=(80, 24)) as pilot:
            await _loaded(pilot)
            table = app.screen.query_one("#fleet", FleetTable)
            while table.row_count < 1000:
                await pilot.pause(0.05)
            assert table.row_at(0)[1] == "error"
            assert table.row_at(999)[1] == "idle"
            assert table.scroll_offset.y == 0
            await pilot.press("pagedown", "pagedown")
            assert table.cursor > 20
            assert table.scroll_offset.y > 0
            await pilot.press("end")
            await pilot.pause()
            assert table.cursor_printer() == table.order[-1]
            assert table.scroll_offset.y == 1000 - table.scrollable_content_region.height
            await pilot.press("home", "slash", *"heat")
            await pilot.pause(0.2)
            assert table.row_count == 125
            assert {table.row_at(i)[1] for i in range(125)} == {
                "heating"}
            counts = str(app.screen.query_one("#counts").render())
            assert "1000 printers" in counts
            assert "125" in counts
            assert "error 125" in counts

    asyncio.run(scenario())


class QueuedFleet(FixedFleet):
    """Items put on a queue by the test, in order; commands recorded."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[StatusItem | EventItem | AvailabilityItem] = asyncio.Queue()
        self.sent: list[tuple[str, str]] = []

    async def _items(self) -> AsyncIterator[StatusItem | EventItem | AvailabilityItem]:
        while True:
            yield await self.queue.get()

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        self.sent.append((printer, cmd))


def test_the_open_printer_gets_its_own_items_its_refusals_and_its_last_will() -> None:
    from support.waiting import until

    from tui.printer_screen import PrinterScreen
    from tui.sources import GONE

    async def scenario() -> None:
        source = QueuedFleet()
        app = FleetApp(source, refresh_s=0.05)
        async with app.run_test(size=(80, 24)) as pilot:
            fleet = app.screen
            source.queue.put_nowait(StatusItem("a", snapshot(1, NOW, "printing", NOW - 60)))
            source.queue.put_nowait(StatusItem("b", snapshot(2, NOW, "idle", NOW - 60)))
            table = fleet.query_one("#fleet", FleetTable)
            await until(lambda: table.row_count == 2)
            await pilot.press("enter")  # "a": printing sorts above idle
            await until(lambda: isinstance(app.screen, PrinterScreen))
            screen = app.screen
            assert screen.printer == "a"
            assert screen.snapshot.state == "printing"
            await pilot.press("p")
            assert source.sent == [("a", "pause")]
            reason = "commands are disabled (mqtt.allow_commands = false)"
            source.queue.put_nowait(EventItem("b", {"event": "error", "cmd": "cancel",
                                                    "reason": "not a's", "ts": NOW}))
            source.queue.put_nowait(EventItem("a", {"event": "error", "cmd": "pause",
                                                    "reason": reason, "ts": NOW}))
            source.queue.put_nowait(StatusItem("b", snapshot(2, NOW + 1, "error", NOW - 60)))
            source.queue.put_nowait(AvailabilityItem("a", False))
            await until(lambda: screen.snapshot.state == "offline")
            assert screen.snapshot.error == GONE
            assert screen.snapshot.job is not None  # its last job stays shown
            texts = [text for _ts, _colour, text in screen.events]
            assert f"refused pause: {reason}" in texts
            assert not any("not a's" in text for text in texts)
            await pilot.press("escape")
            assert app.screen is fleet
            assert fleet.opened is None
            await pilot.press("enter")  # "b" now sorts first (error), "a" offline next
            await until(lambda: isinstance(app.screen, PrinterScreen))
            assert app.screen.printer == "b"
            assert app.screen.snapshot.state == "error"  # shown at once from the fleet's model

    asyncio.run(scenario())
