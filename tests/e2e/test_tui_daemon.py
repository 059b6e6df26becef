"""The dashboard driven by Textual's Pilot against a real daemon on the simulated printer."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
from support.daemon_helpers import commands, layer_commands, two_bodies
from support.daemon_process import sim_config
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA
from support.waiting import until

from hostd.api import ControlClient, ControlError
from hostd.publishing.layerview import parse_layer
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings
from tui.app import Dashboard
from tui.printer_screen import PrinterScreen
from tui.sources import SocketSource
from tui.widgets.dialogs import ConfirmScreen, ObjectsScreen
from tui.widgets.layer import LayerView

PARK = ["G91", "G1 Z5.00 F600", "G90", "M83"]
UNPARK = ["G91", "G1 Z-5.00 F600", "G90", "M83"]


def picture(screen: PrinterScreen) -> str:
    """The layer view's text as drawn (braille dots, no colours)."""
    return screen.query_one(LayerView).picture()


def test_status_layer_picture_pause_and_resume_reach_the_printer(daemon) -> None:
    hostd = daemon(sim_config(time_scale=0.003))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    hostd.drop(DATA / "dogbone_100x30x5.stl", "dogbone.stl")

    async def scenario() -> None:
        app = Dashboard(SocketSource(str(socket)))
        async with app.run_test(size=(80, 24)) as pilot:
            screen = app.printer_screen
            await until(lambda: screen.snapshot.job is not None, 30, "the job in the status")
            await until(lambda: screen.layer_data is not None, 30, "a layer picture")
            first = screen.layer_data["layer"]
            drawn = picture(screen)
            assert any(ch not in "⠀ \n" for ch in drawn)  # dots drawn
            await until(lambda: screen.layer_data["layer"] > first + 1, 60, "later layers")
            assert picture(screen) != drawn
            job = screen.snapshot.job
            assert f"layer {job.layer + 1} of {job.layers}" in str(
                screen.query_one("#job").render().renderables[1])
            await pilot.press("p")
            await until(lambda: screen.snapshot.state == "paused", 10, "paused")
            log = hostd.state / "simulator-executed.log"
            await until(lambda: executed_job_lines(log)[-4:] == PARK, 10, "the nozzle lifted")
            await pilot.press("r")
            await until(lambda: screen.snapshot.state == "printing", 10, "printing again")
            await pilot.press("q")
        assert not app.is_running

    asyncio.run(scenario())
    done = hostd.jobs / "done" / "dogbone.gcode"
    hostd.wait_for(done.exists, 120, "the job done")  # quitting the dashboard left it printing
    assert hostd.stop() == 0
    executed = executed_job_lines(hostd.state / "simulator-executed.log")
    start = executed.index("G91")
    assert executed[start:start + 8] == PARK + UNPARK
    assert executed[:start] + executed[start + 8:] == commands_of(done)


def test_cancel_a_body_from_the_dashboard_and_undo_another(daemon, tmp_path: Path) -> None:
    model = two_bodies(tmp_path / "pair.stl")
    hostd = daemon(sim_config(time_scale=0.003, extra="[runner]\nlookahead = 2\n"))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    hostd.drop(model, "pair.stl")
    cancelled_from: list[int] = []

    async def scenario() -> None:
        app = Dashboard(SocketSource(str(socket)))
        async with app.run_test(size=(120, 40)) as pilot:
            screen = app.printer_screen
            await until(lambda: screen.layer_data is not None
                        and screen.snapshot.state == "printing", 60, "printing")
            await pilot.press("p")  # while paused no further layer is sliced
            await until(lambda: screen.snapshot.state == "paused", 10, "paused")
            log = hostd.state / "simulator-executed.log"
            await until(lambda: executed_job_lines(log)[-4:] == PARK, 10, "the nozzle lifted")
            await until(lambda: screen.layer_data["job"] == screen.snapshot.job.id, 10, "layer")
            assert screen.layer_data["body_count"] == 2
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen), 5, "the objects list")
            assert screen.query_one(LayerView).highlight == 0
            await pilot.press("c")  # body 0
            await until(lambda: any(e[2].startswith("body 0 cancelled") for e in screen.events),
                        10, "body 0 cancelled")
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen), 5, "the objects list")
            await pilot.press("u")  # undo: its next layer is not sliced yet
            await until(lambda: any(e[2] == "body 0 restored" for e in screen.events), 10,
                        "body 0 restored")
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen), 5, "the objects list")
            await pilot.press("down")
            assert screen.query_one(LayerView).highlight == 1
            await pilot.press("c")
            await until(lambda: any(e[2].startswith("body 1 cancelled") for e in screen.events),
                        10, "body 1 cancelled")
            cancelled_from.append(screen.layer_data["next_unsliced"])
            async with ControlClient(str(socket)) as client:
                with pytest.raises(ControlError, match="layer 99 does not exist"):
                    await client.request("layer", layer=99)
                with pytest.raises(ControlError, match="columns, rows"):
                    await client.request("layer", field=[0, 5])
                with pytest.raises(ControlError, match="object 0 is not cancelled"):
                    await client.request("restore_object", object=0)
                with pytest.raises(ControlError, match="layer_height"):
                    await client.request("estimate", settings={"layer_height": 0.3})
            await pilot.press("r")
            await until(lambda: screen.snapshot.state == "printing", 10, "printing again")
            await until(lambda: screen.layer_data["layer"] > cancelled_from[0], 60, "later layers")
            async with ControlClient(str(socket)) as client:
                with pytest.raises(ControlError, match="too late"):
                    await client.request("restore_object", object=1)
            await pilot.press("c")
            await until(lambda: isinstance(app.screen, ConfirmScreen), 5, "the confirmation")
            await pilot.press("n")  # not cancelled
            await pilot.press("q")

    asyncio.run(scenario())
    done = hostd.jobs / "done" / "pair.gcode"
    hostd.wait_for(done.exists, 120, "the job done")
    assert hostd.stop() == 0
    plan = SlicePlan.from_file(model, SliceSettings())
    first = cancelled_from[0]
    expected = commands(plan.start_gcode())
    expected += layer_commands(lambda index: plan, lambda index: frozenset({1})
                               if index >= first else frozenset(), plan.layer_count)
    expected += commands(plan.end_gcode())
    assert commands_of(done) == expected
    assert 0 < first < plan.layer_count
    # the printed file: both boxes before that layer, one side of the plate only from it on
    middle = (plan.bounds[0] + plan.bounds[2]) / 2
    layers = done.read_text().split(";LAYER:")[1:]
    for index, text in enumerate(layers):
        paths, _count = parse_layer(text.splitlines())
        xs = np.concatenate([coords[:, 0] for _kind, coords, _end in paths])
        sides = {bool(x > middle) for x in (xs.min(), xs.max())}
        assert len(sides) == (1 if index >= first else 2), index


def test_layer_requests_during_a_print_leave_its_gcode_byte_for_byte(daemon, tmp_path) -> None:
    model = two_bodies(tmp_path / "pair.stl")
    hostd = daemon(sim_config(time_scale=0.003, extra="[runner]\nlookahead = 2\n"))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    hostd.drop(model, "quiet.stl")
    quiet = hostd.jobs / "done" / "quiet.gcode"
    hostd.wait_for(quiet.exists, 120, "the job without requests done")
    hostd.drop(model, "asked.stl")
    asked = hostd.jobs / "done" / "asked.gcode"
    answered: list[tuple[int, int]] = []  # (layer asked, first layer not sliced then)

    async def started() -> str:
        async with ControlClient(str(socket)) as client:
            loop = asyncio.get_running_loop()
            deadline = loop.time() + 60
            while True:
                job = (await client.status()).job
                if job is not None and job.name == "asked.stl":
                    return job.id
                assert loop.time() < deadline, "asked.stl never started"
                await asyncio.sleep(0.02)

    async def ask(job: str, worker: int, workers: int) -> None:
        async with ControlClient(str(socket)) as client:
            index = worker
            while not asked.exists():
                field = [20, 10] if index % 2 else None
                try:
                    reply = await client.request("layer", layer=index % 50, field=field)
                except ControlError:  # no job printing any more
                    await asyncio.sleep(0.02)
                    continue
                if reply["job"] == job:
                    answered.append((reply["layer"], reply["next_unsliced"]))
                index += workers

    async def scenario() -> None:
        job = await started()
        async with asyncio.timeout(180):
            await asyncio.gather(*(ask(job, worker, 3) for worker in range(3)))

    asyncio.run(scenario())
    # answered while it printed: layers not sliced yet (sliced again for the view) and
    # layers the daemon held (streamed or made ahead)
    assert any(layer >= ahead for layer, ahead in answered)
    assert any(layer < ahead for layer, ahead in answered)
    assert asked.read_bytes() == quiet.read_bytes()
    assert hostd.stop() == 0
