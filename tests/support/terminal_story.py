"""A dashboard story on a real terminal, for tests/test_tui_terminal.py (run as a script).

``python tests/terminal_story.py printer|fleet`` runs the real app (Textual's own
terminal driver, on whatever terminal it is given) and tells it a story of
status updates, each drawn before the next comes: for ``printer`` a job
printing three layers of the dogbone (progress within each layer, temperatures,
events, a longer queue), then idle; for ``fleet`` thirty printers whose columns
change, one changing state. Then it writes the title ``story-partial`` (an OSC
sequence, in order with the screen updates), has the whole screen repainted,
writes ``story-full`` and quits. What the terminal shows at the first title,
made of partial updates only, must be what the full repaint shows.
"""

from __future__ import annotations

import asyncio
import dataclasses
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from bench.fleetpub import snapshot  # noqa: E402
from hostd.api import JobStatus, PrinterInfo, Snapshot, Temperature, Temps  # noqa: E402
from hostd.jobs.schedule import LayerSchedule  # noqa: E402
from hostd.publishing.layerview import layer_view  # noqa: E402
from slicer.plan import SlicePlan  # noqa: E402
from slicer.settings import SliceSettings  # noqa: E402
from support.waiting import until  # noqa: E402
from tui.app import Dashboard  # noqa: E402
from tui.fleet import FleetApp  # noqa: E402
from tui.sources import EventItem, StatusItem  # noqa: E402
from tui.widgets.layer import LayerView  # noqa: E402

PARTIAL, FULL = "\x1b]0;story-partial\x07", "\x1b]0;story-full\x07"
T0 = 1_700_000_000.0
LAYERS = (3, 4, 5)
STEPS = 6  # statuses within each layer
ACKED_BEFORE = 10_000  # lines acknowledged before layer n: n * ACKED_BEFORE


class Story:
    """Tells the app its items one by one, each drawn before the next."""

    label = "story"

    def __init__(self) -> None:
        self.app: Any = None

    async def drawn(self) -> None:
        """Wait until the screen has been refreshed (and its update written)."""
        done = asyncio.Event()
        self.app.call_after_refresh(done.set)
        await asyncio.wait_for(done.wait(), 10)

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        """Commands are not part of the story."""

    async def finish(self) -> None:
        """Mark the partial screen, repaint it whole, mark again, quit."""
        await self.drawn()
        self.app._driver.write(PARTIAL)
        self.app.screen.refresh()
        await self.drawn()
        self.app._driver.write(FULL)
        self.app.exit()


class PrinterStory(Story):
    """Three layers printed with progress, temperatures and events, then idle."""

    def __init__(self) -> None:
        super().__init__()
        plan = SlicePlan.from_file(ROOT / "tests" / "data" / "dogbone_100x30x5.stl",
                                   SliceSettings())
        self.schedule = LayerSchedule(plan, SliceSettings())
        self.commands: dict[int, int] = {}

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]:
        """The layer reply made by the daemon's own code."""
        if cmd != "layer":
            raise NotImplementedError(cmd)
        reply = layer_view(self.schedule, args["layer"], args.get("tolerance", 0.2), None)
        self.commands[args["layer"]] = reply["commands"]
        return {**reply, "job": "7", "acked_before": args["layer"] * ACKED_BEFORE}

    def status(self, layer: int, step: int, ts: float) -> Snapshot:
        commands = self.commands.get(layer, 200)
        acked = layer * ACKED_BEFORE + commands * step // (STEPS - 1)
        queue = ("bracket.stl", "gear.stl", "clip.stl")[: 1 + (layer > LAYERS[0])]
        return Snapshot(
            state="printing", printer=PrinterInfo("sim", "/dev/ttyACM0", True),
            temps=Temps(Temperature(205.0 + step * 0.7 + layer, 210.0),
                        Temperature(58.0 + step * 0.3, 60.0)),
            job=JobStatus(id="7", name="dogbone.stl", layer=layer, layers=25,
                          progress=(layer + step / STEPS) / 25, lines_acked=acked,
                          elapsed_s=ts - T0 + 60, eta_s=400 - (ts - T0),
                          layers_ready_ahead=3, filament_used_mm=100.0 * layer + step,
                          filament_total_mm=2500.0),
            queue=queue, ts=ts)

    async def stream(self) -> AsyncIterator[StatusItem | EventItem]:
        """The story, as the dashboard's source."""
        screen = self.app.printer_screen
        view = screen.query_one(LayerView)
        ts = T0
        for layer in LAYERS:
            for step in range(STEPS):
                ts += 1.5
                yield StatusItem("sim", self.status(layer, step, ts))
                if step == 0:
                    await until(lambda layer=layer: screen.layer_data is not None
                                     and screen.layer_data["layer"] == layer)
                    yield StatusItem("sim", self.status(layer, step, ts))
                await self.drawn()
            yield EventItem("sim", {"event": "layer", "id": "7", "layer": layer, "layers": 25,
                                    "ts": ts})
            await until(lambda: view.drawn_paths == view.printed_paths())
            await self.drawn()
        idle = dataclasses.replace(self.status(LAYERS[-1], STEPS - 1, ts + 2), state="idle",
                                   job=None, queue=())
        yield StatusItem("sim", idle)
        yield EventItem("sim", {"event": "done", "id": "7", "name": "dogbone.stl", "ts": ts + 2})
        await self.finish()
        await asyncio.Event().wait()


class FleetStory(Story):
    """Thirty printers; each round changes some of their columns, one changes state."""

    def fleet_stream(self) -> AsyncIterator[StatusItem]:
        return self._items()

    def stream(self) -> Any:
        raise NotImplementedError

    async def _items(self) -> AsyncIterator[StatusItem]:
        states = ("printing", "idle", "printing", "paused", "printing", "error")
        for round_ in range(8):
            now = T0 + 7.0 * round_
            for index in range(30):
                if round_ and index % (1 + round_ % 3):
                    continue  # not every printer changes every round
                state = states[index % len(states)]
                if index == 2 and round_ >= 5:
                    state = "error"  # moves up the table
                yield StatusItem(f"farm-{index:02d}", snapshot(index, now, state, T0 - 600))
            self.app.screen.flush()
            await self.drawn()
        await self.finish()
        await asyncio.Event().wait()


def main() -> int:
    """Run the story named on the command line."""
    story: Story
    if sys.argv[1] == "printer":
        story = PrinterStory()
        app: Any = Dashboard(story)  # type: ignore[arg-type]
    else:
        story = FleetStory()
        app = FleetApp(story, refresh_s=60.0)  # type: ignore[arg-type]  # flushed by the story
    story.app = app
    app.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
