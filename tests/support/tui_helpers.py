"""What the dashboard tests share: a fixed clock, a printing snapshot, and a source that
tells a fixed story (status history, events, real layer replies)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

from hostd.api import (
    ControlError,
    InterruptedJob,
    JobStatus,
    PrinterInfo,
    Snapshot,
    Temperature,
    Temps,
)
from hostd.jobs.schedule import LayerSchedule
from hostd.publishing.layerview import layer_view
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings
from support.paths import DATA
from tui.sources import EventItem, StatusItem

T0 = 1_700_000_000.0  # a fixed clock for deterministic pictures


def printing(ts: float, hotend: float = 209.5, bed: float = 59.8, lines: int = 2400) -> Snapshot:
    """The dogbone printing its 13th layer of 25, with a queue and an interrupted job."""
    return Snapshot(
        state="printing",
        printer=PrinterInfo("sim", "/dev/ttyACM0", True),
        temps=Temps(hotend=Temperature(hotend, 210.0), bed=Temperature(bed, 60.0)),
        job=JobStatus(id="7", name="dogbone.stl", layer=12, layers=25, progress=0.48,
                      lines_acked=lines, elapsed_s=95.0, eta_s=103.0, layers_ready_ahead=3),
        queue=("bracket.stl", "gear.stl"),
        interrupted=(InterruptedJob(id="5", name="bunny.stl", layer=40),),
        ts=ts,
    )


def history() -> list[StatusItem]:
    """Ten minutes of heating up and printing, one snapshot every 10 s."""
    items = []
    for k in range(60):
        t = k / 60
        items.append(StatusItem("sim", printing(T0 - 600 + 10 * k, hotend=25 + 185 * min(1, 3 * t),
                                                bed=22 + 38 * min(1, 2 * t))))
    return [*items, StatusItem("sim", printing(T0))]


EVENTS = [
    EventItem("sim", {"event": "started", "id": "7", "name": "dogbone.stl", "layers": 25,
                      "resumed_from": None, "ts": T0 - 100}),
    *(EventItem("sim", {"event": "layer", "id": "7", "layer": n, "layers": 25,
                        "ts": T0 - 90 + 8 * n}) for n in range(12)),
]


class FixedSource:
    """A source that tells a fixed story: status snapshots, events, and a real layer reply.

    The layer reply is made by the daemon's own code (``hostd.publishing.layerview``) from the
    dogbone; commands are recorded, and those in ``refuse`` refused.
    """

    label = "fixed source"

    def __init__(self, items: list[StatusItem | EventItem] | None = None,
                 refuse: tuple[str, ...] = ()) -> None:
        self.items = items if items is not None else [*history(), *EVENTS]
        self.refuse = refuse
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.queries: list[tuple[str, dict[str, Any]]] = []
        plan = SlicePlan.from_file(DATA / "dogbone_100x30x5.stl", SliceSettings())
        self.schedule = LayerSchedule(plan, SliceSettings())

    async def stream(self) -> AsyncIterator[StatusItem | EventItem]:
        for item in self.items:
            yield item
        await asyncio.Event().wait()

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        self.calls.append((cmd, args))
        if cmd in self.refuse:
            raise ControlError(f"{cmd} refused for the test")

    async def query(self, printer: str, cmd: str, **args: Any) -> dict[str, Any]:
        self.queries.append((cmd, args))
        if cmd == "estimate":
            reply = {"layer": 12, "from_layer": 16, "filament_used_mm": 1210.0,
                     "filament_total_mm": 2530.0, "eta_s": 103.0,
                     "settings": {"infill.density": 0.2, "infill.field": "linear",
                                  "nozzle_temp": 210.0, "bed_temp": 60.0},
                     "fields": ["linear", "wave"]}
            if args.get("settings"):
                reply["retuned"] = {"filament_total_mm": 3105.0, "eta_s": 131.0,
                                    "time_ratio": 1.27}
            return reply
        field = tuple(args["field"]) if args.get("field") else None
        reply = layer_view(self.schedule, args.get("layer", 12), args.get("tolerance", 0.2), field)
        commands = reply["commands"]
        return {**reply, "job": "7", "acked_before": 2400 - commands // 2, "next_unsliced": 16}
