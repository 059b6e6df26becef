"""The just-in-time runner on the real simulated printer: bounded lookahead, checkpoints.

What needs the wire: the lookahead and the checkpoints under a real link and printer,
renumbering, a slow SQLite store beside the serial reader. What the runner sends and
records (pause, resume, cancel, a resume within a layer, a body cancelled, a full disk,
a lost printer) is tests/unit/test_runner_link.py, against an in-memory link.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import threading
import time
from pathlib import Path

from support.paths import DATA
from support.stores import RecordingStore
from support.waiting import wait_until

from drivers.link.protocol import strip_comment
from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import open_transport
from drivers.sim.config import SimulatorConfig
from drivers.sim.printer import SimulatedPrinter
from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstate import JobState
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.checkpoints import CheckpointWriter
from hostd.printing.runner import JobRunner, _extrudes, open_output
from hostd.printing.sources import SlicedSource
from hostd.publishing.status import StatusHub
from slicer.fields.stress_pending import waited_for, waiting
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

MODEL = DATA / "dogbone_100x30x5.stl"
FIELD_FILE = "analysis-being-computed.npz"  # a field file a layer waits for (never written)
WAITING_LAYER = 2


class CountingSchedule(LayerSchedule):
    """A schedule that counts the layers sliced so far (from the worker threads)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.sliced: list[int] = []
        self.hub: StatusHub | None = None
        self.shown_waiting = False
        self._count_lock = threading.Lock()

    def layer_gcode(self, layer: int) -> list[str]:
        if layer == WAITING_LAYER and self.hub is not None:
            # this layer waits for a field file being computed, as a stress layer waits
            # for its analysis: the status must say so while it waits
            with waiting(FIELD_FILE):
                self.shown_waiting = wait_until(
                    lambda: self.hub.current.job is not None
                    and self.hub.current.job.waiting_for == "analysis", 30.0,
                    "the status to say the layer waits for the analysis")
        lines = super().layer_gcode(layer)
        with self._count_lock:
            self.sliced.append(layer)
        return lines


async def print_job(
    tmp_path: Path, depth: int, renumber_at: int = 100_000, output_path: Path | None = None,
    commit_delay_s: float = 0.0, time_scale: float = 0.0,
) -> dict:
    settings = SliceSettings()
    plan = SlicePlan.from_file(MODEL, settings)
    schedule = CountingSchedule(plan, settings)
    store = RecordingStore(tmp_path / "jobs.sqlite3", commit_delay_s)
    job = store.add("dogbone.stl", str(MODEL), str(MODEL), "stl", "00", settings.to_mapping())
    store.transition(job.id, "slicing")
    hub = StatusHub()
    seen: dict = {"ahead": [], "sliced_at_first_send": None, "sliced_at_first_extrusion": None,
                  "acks": 0, "acks_in_commits": 0, "sends_in_commits": 0, "ack_times": []}
    printer = SimulatedPrinter(SimulatorConfig(time_scale=time_scale, baud=0))
    path = printer.start()
    executor = concurrent.futures.ThreadPoolExecutor(2)
    try:
        config = StreamerConfig(renumber_at=renumber_at)
        transport = await open_transport(path, 250000)
        write_now = transport.write_now
        source: SlicedSource | None = None

        def observed(data: bytes) -> None:
            """Each line as it goes on the wire: what was sliced, what was under way."""
            for framed in data.decode("ascii").splitlines():
                command = framed.split(" ", 1)[-1].rsplit("*", 1)[0]
                if source is None or command.split()[0] in HOUSEKEEPING:
                    continue
                if seen["sliced_at_first_send"] is None and not command.startswith(("M1", "G28")):
                    seen["sliced_at_first_send"] = len(schedule.sliced)
                if seen["sliced_at_first_extrusion"] is None and _extrudes(command):
                    with schedule._count_lock:
                        seen["sliced_at_first_extrusion"] = sorted(schedule.sliced)
                seen["ahead"].append(source.ready_ahead)
                seen["sends_in_commits"] += bool(store.commits.under_way)
            write_now(data)

        transport.write_now = observed  # type: ignore[method-assign]
        async with Streamer(transport, config) as link:
            await link.connect()
            source = SlicedSource(schedule, 0, depth, executor, resume=False)
            output = open_output(output_path or tmp_path / "out.gcode.part", 0)
            runner = JobRunner(job, source, link, JobLife(store, hub), output, 0,
                               write_preamble=True)
            schedule.hub = hub
            runner.waiting = lambda: "analysis" if waited_for(FIELD_FILE) else None
            original_ack = runner.on_ack

            def on_ack(ack) -> None:
                # read by the serial reader and handed over: was a commit under way?
                seen["acks_in_commits"] += bool(store.commits.under_way)
                seen["acks"] += 1
                seen["ack_times"].append(time.monotonic())
                original_ack(ack)

            runner.on_ack = on_ack  # type: ignore[method-assign]
            await runner.run()
            with contextlib.suppress(OSError):
                output.close()
    finally:
        executor.shutdown()
        printer.stop()
    seen["stats"] = link.stats
    seen["loop_thread"] = threading.current_thread().name
    seen["checkpoints"] = store.checkpoints
    seen["threads"] = store.threads
    seen["commits"] = store.commits.spans
    seen["job"] = store.get(job.id)
    seen["executed"] = list(printer.executed)
    seen["plan"] = plan
    seen["hub"] = hub.current
    seen["shown_waiting"] = schedule.shown_waiting
    seen["output_error"] = runner.output_error
    store.close()
    return seen


HOUSEKEEPING = ("M110", "M115", "M503", "M155", "M105")


def whole_program(plan) -> list[str]:
    """The commands of the whole print: start, every layer, ending."""
    expected = [c for c in map(strip_comment, plan.start_gcode()) if c]
    for index in range(plan.layer_count):
        expected += [c for c in map(strip_comment, plan.layer_gcode(index)) if c]
    return expected + [c for c in map(strip_comment, plan.end_gcode()) if c]


def job_lines(executed: list[str]) -> list[str]:
    """The executed commands less the link's own (renumbering, capabilities, probes)."""
    return [c for c in executed if c.split()[0] not in HOUSEKEEPING]

def test_layers_are_sliced_just_ahead_and_checkpointed_as_acknowledged(tmp_path: Path) -> None:
    seen = asyncio.run(print_job(tmp_path, depth=3))
    plan = seen["plan"]
    layers = plan.layer_count
    # never the whole file first: streaming began with at most the lookahead sliced
    assert seen["sliced_at_first_send"] is not None
    assert seen["sliced_at_first_send"] <= 3
    # and the layers after the first wait until the printer took its first extruding
    # move: nothing competes with the lines it waits for
    assert seen["sliced_at_first_extrusion"] == [0]
    assert max(seen["ahead"]) <= 3  # bounded: backpressure
    # checkpoints in order: layers, line counts and file offsets never go back; a newer
    # one replaces one not yet written, and the last records the last layer
    checkpoints = seen["checkpoints"]
    assert all(a[0] <= b[0] and a[1] < b[1] and a[2] <= b[2]
               for a, b in itertools.pairwise(checkpoints))
    assert checkpoints[-1][0] == layers - 1
    # within a layer, the commands of the next layer acknowledged so far
    assert any(c[3] > 0 and c[0] < layers - 1 for c in checkpoints)
    expected = [c for c in map(strip_comment, plan.start_gcode()) if c]
    for index in range(layers):
        expected += [c for c in map(strip_comment, plan.layer_gcode(index)) if c]
    ending = [c for c in map(strip_comment, plan.end_gcode()) if c]
    expected += ending
    executed = job_lines(seen["executed"])
    assert executed == expected
    job = seen["job"]
    assert (job.state, job.layer, job.layers) == ("printing", layers - 1, layers)
    # the last checkpoint: every line acknowledged, the ending's after the last layer
    assert job.lines_acked == len(expected) == checkpoints[-1][1]
    assert job.layer_lines == len(ending)
    text = (tmp_path / "out.gcode.part").read_text()
    assert [c for c in map(strip_comment, text.splitlines()) if c] == expected
    assert job.gcode_bytes <= len(text.encode())
    assert seen["hub"].job.progress == 1.0
    assert seen["hub"].state == "printing"
    # while a layer waited for the analysis the status said so, and no longer after
    assert seen["shown_waiting"]
    assert seen["hub"].job.waiting_for is None


def test_checkpoints_go_on_when_the_streamer_renumbers_lines(tmp_path: Path) -> None:
    seen = asyncio.run(print_job(tmp_path, depth=2, renumber_at=1000))
    executed = seen["executed"]
    renumbered = sum(c.startswith("M110") for c in executed)
    # renumbered at every 1000th line number: at least once per 1000 job lines
    assert renumbered >= 2
    assert renumbered >= (len(executed) - renumbered) // 1000
    layers = [c[0] for c in seen["checkpoints"]]
    assert layers == sorted(layers)
    assert layers[-1] == seen["plan"].layer_count - 1


def test_a_store_whose_commits_take_200_ms_does_not_hold_up_the_printer(tmp_path: Path) -> None:
    instant = asyncio.run(print_job(tmp_path / "instant", depth=3, time_scale=0.002))
    seen = asyncio.run(print_job(tmp_path / "slow", depth=3, commit_delay_s=0.2,
                                 time_scale=0.002))
    plan = seen["plan"]
    expected = whole_program(plan)
    # every line carried out exactly once, in order, as with a store that takes no time
    assert job_lines(seen["executed"]) == expected == job_lines(instant["executed"])
    assert len(seen["executed"]) == len(instant["executed"])
    stats, before = seen["stats"], instant["stats"]
    assert (stats.resends, stats.lines_resent, stats.probes, stats.errors) == (0, 0, 0, 0)
    assert (stats.resends, stats.lines_resent, stats.probes, stats.errors) == (
        before.resends, before.lines_resent, before.probes, before.errors)
    # the commits ran in the writer's thread, never in the loop that reads the printer:
    # while the printer acknowledged lines, no commit ran there (the job's move to
    # printing included), and acknowledgements went on being read and lines sent
    # while commits were under way
    assert seen["threads"]
    assert set(seen["threads"]) == {"hostd-checkpoint_0"}
    first_ack, last_ack = seen["ack_times"][0], seen["ack_times"][-1]
    while_printing = [(a, b, thread) for a, b, thread in seen["commits"]
                      if b > first_ack and a < last_ack]
    assert len(while_printing) >= 5
    assert {thread for _a, _b, thread in while_printing} == {"hostd-checkpoint_0"}
    assert seen["loop_thread"] != "hostd-checkpoint_0"
    assert seen["acks_in_commits"] > seen["acks"] // 2
    assert seen["sends_in_commits"] > len(expected) // 2
    # the move to printing is recorded all the same, and the store ends at the last
    # layer, with every line acknowledged
    assert seen["job"].state == "printing"
    assert seen["checkpoints"][-1][0] == plan.layer_count - 1
    assert seen["job"].lines_acked == seen["checkpoints"][-1][1]


def test_a_state_change_handed_to_the_checkpoint_writer_is_committed_off_the_loop_in_order(
    tmp_path: Path,
) -> None:
    store = RecordingStore(tmp_path / "jobs.sqlite3", commit_delay_s=0.2)
    job = store.add("dogbone.stl", str(MODEL), str(MODEL), "stl", "00", {})
    for state in ("slicing", "heating"):
        store.transition(job.id, state)
    hub = StatusHub()
    life = JobLife(store, hub)
    shown: list[tuple[str, str]] = []

    async def main() -> int:
        writer = CheckpointWriter(store, job.id, None, lambda what, message: None)
        ticks_in_commits = 0
        stop = asyncio.Event()

        async def ticker() -> None:
            nonlocal ticks_in_commits
            while not stop.is_set():
                ticks_in_commits += bool(store.commits.under_way)
                await asyncio.sleep(0.005)

        ticking = asyncio.create_task(ticker())
        writer.submit_state(
            lambda connection: life.record(job.id, JobState.PRINTING, store=connection),
            lambda: shown.append((store.get(job.id).state, threading.current_thread().name)),
        )
        assert shown == []  # handed over: nothing waited for the store here
        await writer.states_written()
        life.enter(job.id, JobState.PAUSED)  # a command after it, in the loop
        stop.set()
        await ticking
        await writer.close()
        return ticks_in_commits

    ticks = asyncio.run(main())
    # shown once recorded, in the loop; the loop ran on while the commit was under way
    assert shown == [("printing", threading.current_thread().name)]
    assert ticks > 0
    moves = [entry.to_state for entry in store.history(job.id)]
    assert moves == ["queued", "slicing", "heating", "printing", "paused"]
    printing = [thread for _a, _b, thread in store.commits.spans][-2]
    assert printing == "hostd-checkpoint_0"
    assert hub.current.state == "paused"
    store.close()
