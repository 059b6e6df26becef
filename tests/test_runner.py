"""The just-in-time runner on the real simulated printer: bounded lookahead, checkpoints."""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import threading
from pathlib import Path

from conftest import DATA

from drivers.protocol import strip_comment
from drivers.simconfig import SimulatorConfig
from drivers.simulator import SimulatedPrinter
from drivers.streamer import Streamer, StreamerConfig
from drivers.transport import open_transport
from hostd.jobstore import JobStore
from hostd.runner import JobRunner, open_output
from hostd.schedule import LayerSchedule
from hostd.sources import SlicedSource
from hostd.status import StatusHub
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

MODEL = DATA / "dogbone_100x30x5.stl"


class CountingSchedule(LayerSchedule):
    """A schedule that counts the layers sliced so far (from the worker threads)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.sliced: list[int] = []
        self._count_lock = threading.Lock()

    def layer_gcode(self, layer: int) -> list[str]:
        lines = super().layer_gcode(layer)
        with self._count_lock:
            self.sliced.append(layer)
        return lines


async def print_job(
    tmp_path: Path, depth: int, renumber_at: int = 100_000, output_path: Path | None = None
) -> dict:
    settings = SliceSettings()
    plan = SlicePlan.from_file(MODEL, settings)
    schedule = CountingSchedule(plan, settings)
    store = JobStore(tmp_path / "jobs.sqlite3")
    job = store.add("dogbone.stl", str(MODEL), str(MODEL), "stl", "00", settings.to_mapping())
    store.transition(job.id, "slicing")
    hub = StatusHub()
    seen: dict = {"ahead": [], "sliced_at_first_send": None, "checkpoints": []}
    printer = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=0))
    path = printer.start()
    executor = concurrent.futures.ThreadPoolExecutor(2)
    try:
        config = StreamerConfig(renumber_at=renumber_at)
        async with Streamer(await open_transport(path, 250000), config) as link:
            await link.connect()
            source = SlicedSource(schedule, 0, depth, executor, resume=False)
            output = open_output(output_path or tmp_path / "out.gcode.part", 0)
            runner = JobRunner(job, source, link, store, hub, output, 0, write_preamble=True)
            original_send = link.send

            async def send(command: str) -> int:
                if seen["sliced_at_first_send"] is None and not command.startswith(("M1", "G28")):
                    seen["sliced_at_first_send"] = len(schedule.sliced)
                seen["ahead"].append(source.ready_ahead)
                return await original_send(command)

            link.send = send  # type: ignore[method-assign]
            original_checkpoint = store.checkpoint

            def checkpoint(job_id: str, layer: int, lines: int, offset: int) -> None:
                seen["checkpoints"].append((layer, lines, offset))
                original_checkpoint(job_id, layer, lines, offset)

            store.checkpoint = checkpoint  # type: ignore[method-assign]
            link.on_ack = lambda _number, _command: runner.on_ack()
            await runner.run()
            with contextlib.suppress(OSError):
                output.close()
    finally:
        executor.shutdown()
        printer.stop()
    seen["job"] = store.get(job.id)
    seen["executed"] = list(printer.executed)
    seen["plan"] = plan
    seen["hub"] = hub.current
    seen["output_error"] = runner.output_error
    store.close()
    return seen


def test_layers_are_sliced_just_ahead_and_checkpointed_as_acknowledged(tmp_path: Path) -> None:
    seen = asyncio.run(print_job(tmp_path, depth=3))
    plan = seen["plan"]
    layers = plan.layer_count
    # never the whole file first: streaming began with at most the lookahead sliced
    assert seen["sliced_at_first_send"] is not None and seen["sliced_at_first_send"] <= 3
    assert max(seen["ahead"]) <= 3  # bounded: backpressure
    # one checkpoint per layer, in order, with growing line counts and file offsets
    checkpoints = seen["checkpoints"]
    assert [c[0] for c in checkpoints] == list(range(layers))
    assert all(a[1] < b[1] and a[2] < b[2] for a, b in itertools.pairwise(checkpoints))
    expected = [c for c in map(strip_comment, plan.start_gcode()) if c]
    for index in range(layers):
        expected += [c for c in map(strip_comment, plan.layer_gcode(index)) if c]
    ending = [c for c in map(strip_comment, plan.end_gcode()) if c]
    expected += ending
    housekeeping = ("M110", "M115", "M155", "M105")
    executed = [c for c in seen["executed"] if c.split()[0] not in housekeeping]
    assert executed == expected
    job = seen["job"]
    assert (job.state, job.layer, job.layers) == ("printing", layers - 1, layers)
    # the last checkpoint: every line up to the last layer acknowledged
    assert job.lines_acked == len(expected) - len(ending) == checkpoints[-1][1]
    text = (tmp_path / "out.gcode.part").read_text()
    assert [c for c in map(strip_comment, text.splitlines()) if c] == expected
    assert job.gcode_bytes <= len(text.encode())
    assert seen["hub"].job.progress == 1.0 and seen["hub"].state == "printing"


def test_checkpoints_go_on_when_the_streamer_renumbers_lines(tmp_path: Path) -> None:
    seen = asyncio.run(print_job(tmp_path, depth=2, renumber_at=1000))
    # renumbered often: the line budget cut the job to about 9,000 lines
    assert sum(c.startswith("M110") for c in seen["executed"]) >= 8
    assert [c[0] for c in seen["checkpoints"]] == list(range(seen["plan"].layer_count))


def test_a_full_disk_stops_the_gcode_file_but_not_the_print(tmp_path: Path) -> None:
    seen = asyncio.run(print_job(tmp_path, depth=2, output_path=Path("/dev/full")))
    plan = seen["plan"]
    expected = [c for c in map(strip_comment, plan.start_gcode()) if c]
    for index in range(plan.layer_count):
        expected += [c for c in map(strip_comment, plan.layer_gcode(index)) if c]
    expected += [c for c in map(strip_comment, plan.end_gcode()) if c]
    housekeeping = ("M110", "M115", "M155", "M105")
    assert [c for c in seen["executed"] if c.split()[0] not in housekeeping] == expected
    assert "No space left on device" in seen["output_error"]
    assert seen["hub"].job.progress == 1.0
