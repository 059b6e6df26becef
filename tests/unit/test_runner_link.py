"""The just-in-time runner against an in-memory link: what it sends, in which order,
what it records and reports; no wire, no printer, no database.

The runner on the real simulated printer (lookahead under a real link, renumbering,
a slow store) is tests/integration/test_runner.py.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import trimesh
from support.fake_link import FakeLink
from support.memory_store import MemoryStore

from drivers.link.errors import LinkError
from drivers.link.protocol import strip_comment
from hostd.jobs.joblife import JobLife
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.reentry import reentry_moves
from hostd.printing.runner import (
    ENDING,
    PREAMBLE,
    JobCancelled,
    JobLine,
    JobRunner,
    open_output,
    park_moves,
)
from hostd.printing.sources import SlicedSource
from hostd.publishing.status import StatusHub
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

LAYERS = 6
PREAMBLE_LINES = ["M140 S60", "M104 S200", "G28 ; home", "M83"]
ENDING_LINES = ["M104 S0", "M140 S0", "M84"]
PARK = park_moves(1.0)
END_GCODE = ("M104 S0", "G28 X0 Y0")


def layer_lines(index: int) -> list[str]:
    """Layer ``index``: a comment, the Z move and four extruding sides of a square."""
    z = 0.2 * (index + 1)
    return [f";LAYER:{index}", f"G1 Z{z:.2f} F600", "G1 X10 Y10 F3000",
            "G1 X30 Y10 E0.8 F1800", "G1 X30 Y30 E0.8", "G1 X10 Y30 E0.8", "G1 X10 Y10 E0.8"]


def commands(lines: list[str]) -> list[str]:
    return [c for c in map(strip_comment, lines) if c]


PROGRAM = commands(PREAMBLE_LINES + [line for i in range(LAYERS) for line in layer_lines(i)]
                   + ENDING_LINES)
FIRST_LAYER_AT = len(commands(PREAMBLE_LINES))
PER_LAYER = len(commands(layer_lines(0)))


@dataclass
class ListSource:
    """A job whose layers are ready: ``hostd.printing.sources.LayerSource`` over fixed lines."""

    first: int = 0
    preamble_lines: list[str] = field(default_factory=lambda: list(PREAMBLE_LINES))
    layer_count: int = LAYERS
    started_at: list[int] = field(default_factory=list)  # lines taken when started() came
    taken: int = 0

    def preamble(self) -> list[str]:
        return self.preamble_lines

    async def layer(self, index: int) -> list[str]:
        await asyncio.sleep(0)  # a layer is made elsewhere: the loop runs meanwhile
        self.taken = index + 1
        return layer_lines(index)

    def ending(self) -> list[str]:
        return list(ENDING_LINES)

    def started(self) -> None:
        self.started_at.append(self.taken)

    @property
    def ready_ahead(self) -> int:
        return 0

    def held(self, index: int) -> list[str] | None:
        return None

    @property
    def next_unsliced(self) -> int:
        return self.taken

    def close(self) -> None:
        pass


@dataclass
class Run:
    """One job on the fake link: the runner, its store, and the events it published."""

    runner: JobRunner
    link: FakeLink
    store: MemoryStore
    hub: StatusHub
    events: list[dict[str, Any]]
    output: Path

    @property
    def job(self):
        return self.store.get(self.runner.job.id)

    def kinds(self) -> list[str]:
        return [event["event"] for event in self.events]


def start(tmp_path: Path, link: FakeLink, source: Any = None, first: int = 0, skip: int = 0,
          output: Path | None = None, job_fields: dict[str, Any] | None = None) -> Run:
    store = MemoryStore()
    job = store.add("square.stl")
    store.transition(job.id, "slicing")
    if job_fields:
        store.checkpoint(job.id, **job_fields)
    job = store.get(job.id)
    hub = StatusHub()
    events: list[dict[str, Any]] = []
    hub.listen(events.append)
    path = output or tmp_path / "out.gcode.part"
    keep = job.gcode_bytes if first or skip else 0
    runner = JobRunner(job, source or ListSource(first=first), link, JobLife(store, hub),
                       open_output(path, keep), first, write_preamble=not (first or skip),
                       park=PARK, skip=skip, end_gcode=END_GCODE)
    return Run(runner, link, store, hub, events, path)


async def until(check: Callable[[], object], what: str, turns: int = 10_000) -> None:
    """Let the loop run until ``check()`` is true (counted in turns of the loop: no clock)."""
    for _ in range(turns):
        if check():
            return
        await asyncio.sleep(0)
    raise AssertionError(f"{what}: not after {turns} turns of the loop")


def job_tags(link: FakeLink) -> list[JobLine]:
    return [tag for tag in link.tags if isinstance(tag, JobLine)]


def test_a_job_streams_every_line_tagged_in_order_and_records_each_layer(tmp_path: Path) -> None:
    run = start(tmp_path, FakeLink())
    asyncio.run(run.runner.run())
    assert run.link.executed == PROGRAM
    # each job line tagged: its place in the run, its layer, its index in the layer
    tags = job_tags(run.link)
    assert [tag.seq for tag in tags] == list(range(len(PROGRAM)))
    assert [tag.layer for tag in tags] == (
        [PREAMBLE] * FIRST_LAYER_AT
        + [layer for layer in range(LAYERS) for _ in range(PER_LAYER)]
        + [ENDING] * len(ENDING_LINES))
    assert [tag.index for tag in tags if tag.layer == 3] == list(range(PER_LAYER))
    # the printer took the first extruding move before the later layers were asked for
    assert run.runner.source.started_at == [1]
    # slicing -> heating -> printing; the store ends at the last layer, every line counted
    job = run.job
    assert run.store.states(job.id) == ["queued", "slicing", "heating", "printing"]
    assert (job.layer, job.lines_acked, job.layer_lines) == (
        LAYERS - 1, len(PROGRAM), len(ENDING_LINES))
    checkpoints = run.store.checkpoints
    assert all(a[0] <= b[0] and a[1] < b[1] and a[2] <= b[2]
               for a, b in itertools.pairwise(checkpoints))
    assert set(run.store.threads) == {"hostd-checkpoint_0"}  # never in the loop
    # one event per layer, in order; the G-code file holds the whole job with comments
    assert [e["layer"] for e in run.events if e["event"] == "layer"] == list(range(LAYERS))
    text = run.output.read_text()
    assert commands(text.splitlines()) == PROGRAM
    assert ";LAYER:5" in text
    assert job.gcode_bytes == len(text.encode()) - len("\n".join(ENDING_LINES) + "\n")
    status = run.runner.status()
    assert (status.progress, status.lines_acked) == (1.0, len(PROGRAM))
    assert run.hub.current.state == "printing"


def test_pause_holds_every_job_line_and_parks_until_resume_puts_the_nozzle_back(
    tmp_path: Path,
) -> None:
    stop = FIRST_LAYER_AT + 2 * PER_LAYER + 3  # three commands into layer 2
    run = start(tmp_path, FakeLink(hold_at=stop))

    async def main() -> tuple[list[str], str]:
        printing = asyncio.create_task(run.runner.run())
        await run.link.holding.wait()
        await until(lambda: run.runner.completed == 1, "layers 0 and 1 acknowledged")
        await run.runner.pause()
        run.link.release()  # the line the runner was sending now meets the pause
        await run.link.waiting_resume.wait()
        held = run.link.executed[stop:]
        state = run.job.state
        await run.runner.resume()
        await printing
        return held, state

    held, state = asyncio.run(main())
    # nothing of the job while paused: only the lift off the part
    assert held == list(PARK.park)
    assert state == "paused"
    assert run.link.executed == [*PROGRAM[:stop], *PARK.park, *PARK.unpark, *PROGRAM[stop:]]
    assert run.store.states(run.job.id)[-3:] == ["printing", "paused", "printing"]
    paused = next(e for e in run.events if e["event"] == "paused")
    assert paused["layer"] == 1
    assert run.kinds().index("paused") < run.kinds().index("resumed")
    assert [e["layer"] for e in run.events if e["event"] == "layer"] == list(range(LAYERS))


def test_a_pause_before_the_print_starts_lifts_nothing(tmp_path: Path) -> None:
    run = start(tmp_path, FakeLink(hold_at=2))  # within the start block: nothing printed yet

    async def main() -> None:
        printing = asyncio.create_task(run.runner.run())
        await run.link.holding.wait()
        await run.runner.pause()
        run.link.release()
        await run.link.waiting_resume.wait()
        assert run.job.state == "paused"
        await run.runner.resume()
        await printing

    asyncio.run(main())
    assert run.link.executed == PROGRAM
    # resumed into heating: the printer had not taken the start block yet
    assert run.store.states(run.job.id) == [
        "queued", "slicing", "heating", "paused", "heating", "printing"]


def test_cancel_ends_any_heating_wait_refuses_the_jobs_lines_and_sends_the_end_gcode(
    tmp_path: Path,
) -> None:
    stop = FIRST_LAYER_AT + PER_LAYER + 2
    run = start(tmp_path, FakeLink(hold_at=stop))

    async def main() -> None:
        printing = asyncio.create_task(run.runner.run())
        await run.link.holding.wait()
        await run.runner.cancel()
        await run.runner.cancel()  # a second cancel changes nothing
        with pytest.raises(JobCancelled):
            await printing

    asyncio.run(main())
    assert run.link.executed == [*PROGRAM[:stop], "M108", *END_GCODE]
    assert run.runner.completed == 0
    assert run.job.state == "printing"  # the job's end is its owner's to record


def test_cancel_while_paused_ends_the_job_without_another_line_of_it(tmp_path: Path) -> None:
    stop = FIRST_LAYER_AT + PER_LAYER + 2
    run = start(tmp_path, FakeLink(hold_at=stop))

    async def main() -> None:
        printing = asyncio.create_task(run.runner.run())
        await run.link.holding.wait()
        await until(lambda: run.runner.completed == 0, "layer 0 acknowledged")
        await run.runner.pause()
        run.link.release()
        await run.link.waiting_resume.wait()
        await run.runner.cancel()
        with pytest.raises(JobCancelled):
            await printing
        await run.runner.resume()  # too late: nothing happens

    asyncio.run(main())
    assert run.link.executed == [*PROGRAM[:stop], *PARK.park, "M108", *END_GCODE]


def test_a_resume_within_a_layer_moves_back_untagged_then_sends_the_rest_of_it(
    tmp_path: Path,
) -> None:
    layer, done = 2, 3  # layer 2 complete; 3 commands of layer 3 carried out
    printed = PREAMBLE_LINES + [line for i in range(layer + 1) for line in layer_lines(i)]
    partial = tmp_path / "out.gcode.part"
    partial.write_text("\n".join(printed) + "\n")
    resume_block = ["M104 S200", "G28 X0 Y0", "G1 Z5 F600", "M83"]
    source = ListSource(first=layer + 1, preamble_lines=resume_block)
    run = start(tmp_path, FakeLink(), source=source, first=layer + 1, skip=done, output=partial,
                job_fields={"layer": layer, "lines_acked": 30,
                            "gcode_bytes": partial.stat().st_size, "layer_lines": done})
    asyncio.run(run.runner.run())
    rest = commands(layer_lines(layer + 1))
    carried_out, rest = rest[:done], rest[done:]
    rest += commands([line for i in range(layer + 2, LAYERS) for line in layer_lines(i)])
    rest += commands(ENDING_LINES)
    back = list(reentry_moves(carried_out))
    assert back  # the square's corner, at the layer's height
    assert run.link.executed == resume_block + back + rest
    # the moves back are not the job's lines; the rest keep their index in the layer
    tags = run.link.tags
    assert tags[len(resume_block):len(resume_block) + len(back)] == [None] * len(back)
    first_rest = tags[len(resume_block) + len(back)]
    assert (first_rest.layer, first_rest.index) == (layer + 1, done)
    # the G-code file is the uninterrupted print's; the lines of layer 3 carried out
    # before are not counted again (the resume block's are)
    assert commands(partial.read_text().splitlines()) == PROGRAM
    assert run.job.lines_acked == 30 + len(resume_block) + len(rest)


def test_a_full_disk_stops_the_gcode_file_reports_it_once_and_the_print_goes_on(
    tmp_path: Path,
) -> None:
    run = start(tmp_path, FakeLink(), output=Path("/dev/full"))
    asyncio.run(run.runner.run())
    assert run.link.executed == PROGRAM
    assert "No space left on device" in (run.runner.output_error or "")
    errors = [e for e in run.events if e["event"] == "error"]
    assert len(errors) == 1
    assert "No space left on device" in errors[0]["message"]
    # a job whose file failed cannot resume: its checkpoints are no longer recorded
    assert run.store.checkpoints == []
    assert run.runner.status().progress == 1.0


def test_a_lost_printer_stops_the_run_with_the_links_error_and_the_last_checkpoint_kept(
    tmp_path: Path,
) -> None:
    lost = FIRST_LAYER_AT + 3 * PER_LAYER + 1
    run = start(tmp_path, FakeLink(fail_at=lost))
    with pytest.raises(LinkError, match="stopped answering"):
        asyncio.run(run.runner.run())
    assert run.link.executed == PROGRAM[:lost]
    job = run.job
    assert job.layer == 2  # layers 0-2 acknowledged whole
    assert job.lines_acked == lost
    assert job.layer_lines == 1
    assert [e["layer"] for e in run.events if e["event"] == "layer"] == [0, 1, 2]


# -- a body cancelled mid-print, on the real slicer ------------------------------------


@pytest.fixture(scope="module")
def two_boxes(tmp_path_factory: pytest.TempPathFactory) -> SlicePlan:
    left = trimesh.creation.box((8.0, 8.0, 1.6))
    left.apply_translation((-8.0, 0.0, 0.8))
    right = trimesh.creation.box((8.0, 8.0, 1.6))
    right.apply_translation((8.0, 0.0, 0.8))
    path = tmp_path_factory.mktemp("boxes") / "two_boxes.stl"
    trimesh.util.concatenate([left, right]).export(path)
    return SlicePlan.from_file(path, SliceSettings())


def test_a_body_cancelled_mid_print_is_left_out_of_every_layer_not_sliced_yet(
    tmp_path: Path, two_boxes: SlicePlan,
) -> None:
    settings = SliceSettings()
    schedule = LayerSchedule(two_boxes, settings)
    layers = schedule.layer_count
    executor = concurrent.futures.ThreadPoolExecutor(2)
    source = SlicedSource(schedule, 0, 2, executor, resume=False)
    link = FakeLink()
    run = start(tmp_path, link, source=source)
    cut: list[int] = []

    async def main() -> None:
        link.hold_at = len(commands(two_boxes.start_gcode())) + 1  # into layer 0
        printing = asyncio.create_task(run.runner.run())
        await link.holding.wait()
        first = source.next_unsliced  # as a print's owner does on the command
        schedule.cancel_body(1, first)
        cut.append(first)
        link.release()
        await printing

    try:
        asyncio.run(main())
    finally:
        executor.shutdown()
    (first,) = cut
    assert 0 < first < layers - 1
    sent: dict[int, list[str]] = {}
    for command, tag in zip(link.executed, link.tags, strict=True):
        if isinstance(tag, JobLine) and tag.layer >= 0:
            sent.setdefault(tag.layer, []).append(command)
    sides = {index: sides_printed(lines) for index, lines in sent.items()}
    assert set(sent) == set(range(layers))
    assert all(sides[index] == {-1, 1} for index in range(first))
    kept = {side for index in range(first, layers) for side in sides[index]}
    assert len(kept) == 1
    assert all(sides[index] == kept for index in range(first, layers))
    assert run.job.layer == layers - 1


def sides_printed(lines: list[str]) -> set[int]:
    """Which side of the bed's middle (x = 110) the layer's extruding moves lay plastic."""
    found = set()
    for line in lines:
        words = {w[0]: w[1:] for w in line.split()[1:]}
        if line.startswith("G1") and "X" in words and float(words.get("E", 0)) > 0:
            found.add(1 if float(words["X"]) > 110 else -1)
    return found
