"""A printer's screen opened from the fleet, fed over MQTT only, on a real daemon and mosquitto:
the layer picture, filament, bodies, cancel and undo, retune, and what a printer refuses."""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import aiomqtt
import pytest
from support.brokers import HOST, Broker, start_broker
from support.daemon_helpers import commands, layer_commands, two_bodies
from support.fleet_helpers import REPO, rows
from support.gcode_lines import commands_of
from support.waiting import until

from hostd.api import ControlError
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings
from tui.fleet import FleetApp
from tui.printer_screen import PrinterScreen
from tui.sources import MqttSource
from tui.widgets.dialogs import ConfirmScreen, ObjectsScreen, RetuneScreen
from tui.widgets.layer import LayerView
from tui.widgets.panels import JobPanel

USER, SECRET = "farm", "pw-8"


@pytest.fixture
def broker(tmp_path: Path):
    running = start_broker(tmp_path / "broker", users={USER: SECRET})
    yield running
    running.stop()


def start_daemon(folder: Path, broker: Broker, printer: str, *, allow_commands: bool,
                 time_scale: float = 0.003) -> subprocess.Popen[bytes]:
    """`hostd run` on the simulated printer (slowed down), bridged to ``broker``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "hostd.toml").write_text(
        "[jobs]\nfolder = \"jobs\"\nsettle_s = 0.2\n[state]\nfolder = \"var\"\n"
        f"[printer]\nid = \"{printer}\"\n[simulator]\ntime_scale = {time_scale}\nbaud = 0\n"
        "[runner]\nlookahead = 2\n"
        f"[mqtt]\nenabled = true\nhost = \"{HOST}\"\nport = {broker.port}\n"
        f"username = \"{USER}\"\npassword = \"{SECRET}\"\n"
        f"allow_commands = {str(allow_commands).lower()}\n"
    )
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())",
         "run", "--config", str(folder / "hostd.toml")],
        cwd=folder, env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )


def drop(folder: Path, model: Path) -> None:
    """Put ``model`` into the daemon's job folder at once (written aside, renamed)."""
    jobs = folder / "jobs"
    jobs.mkdir(parents=True, exist_ok=True)
    (jobs / ".part").write_bytes(model.read_bytes())
    os.replace(jobs / ".part", jobs / model.name)


def texts(screen: PrinterScreen) -> list[str]:
    return [text for _ts, _colour, text in screen.events]


def picture(screen: PrinterScreen) -> str:
    return screen.query_one(LayerView).picture()


def panel_line(screen: PrinterScreen, row: int) -> str:
    return screen.query_one(JobPanel).render().renderables[row].plain


async def open_printing(app: FleetApp, pilot, printer: str) -> PrinterScreen:
    """Wait for ``printer`` printing in the fleet, open its screen, wait for its picture."""
    await until(lambda: rows(app) == [(printer, "printing")], timeout=90,
                what=lambda: rows(app))
    await pilot.press("enter")
    await until(lambda: isinstance(app.screen, PrinterScreen))
    screen = app.screen
    assert isinstance(screen, PrinterScreen)
    assert not screen.own_stream  # fed by the fleet's one connection
    await until(lambda: screen.layer_data is not None, timeout=30,
                what=lambda: (str(screen.query_one(LayerView).render()), texts(screen)))
    return screen


def test_over_mqtt_the_picture_filament_bodies_cancel_undo_and_retune_work(
    tmp_path: Path, broker: Broker
) -> None:
    model = two_bodies(tmp_path / "pair.stl")
    folder = tmp_path / "d"
    daemon = start_daemon(folder, broker, "farm8", allow_commands=True)
    source = MqttSource(HOST, broker.port, username=USER, password=SECRET)

    async def scenario() -> None:
        app = FleetApp(source, refresh_s=0.05)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(lambda: rows(app) == [("farm8", "idle")], timeout=40,
                        what=lambda: rows(app))
            drop(folder, model)
            screen = await open_printing(app, pilot, "farm8")
            fleet = app.screen_stack[-2]
            assert list(source._replies) == ["farm8"]  # its replies, while it is open
            data = screen.layer_data
            assert data["job"] == screen.snapshot.job.id
            assert data["body_count"] == 2
            assert any(ch not in "⠀\n " for ch in picture(screen))
            # the filament of the status itself, as the panel shows it
            await until(lambda: screen.snapshot.job.filament_total_mm is not None)
            job = screen.snapshot.job
            assert job.filament_total_mm > 0
            shown = panel_line(screen, 3)
            assert re.search(r"filament ≈\d+\.\d\d of \d+\.\d\d m", shown)
            assert shown.endswith(f" of {screen.snapshot.job.filament_total_mm / 1000:.2f} m")
            # the picture follows the layers, and the field overlay comes over MQTT too
            first = data["layer"]
            await until(lambda: screen.layer_data["layer"] > first, timeout=60)
            await pilot.press("f")
            await until(lambda: (screen.layer_data or {}).get("field") is not None, timeout=30)
            assert screen.layer_data["field"]["name"] == "linear"

            await pilot.press("p")  # paused: no further layer is sliced meanwhile
            await until(lambda: screen.snapshot.state == "paused", timeout=20)
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen))
            assert screen.query_one(LayerView).highlight == 0
            await pilot.press("c")  # body 0, over MQTT
            await until(lambda: any(t.startswith("body 0 cancelled") for t in texts(screen)),
                        what=lambda: texts(screen))
            assert "> cancel_object object=0" in texts(screen)
            await until(lambda: screen.layer_data is not None
                        and screen.layer_data["cancelled"] == [{"object": 0, "from_layer":
                                                                screen.layer_data["next_unsliced"]}],
                        timeout=20, what=lambda: screen.layer_data)
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen))
            await pilot.press("u")  # undone: its first layer without it is not sliced yet
            await until(lambda: "body 0 restored" in texts(screen), what=lambda: texts(screen))
            await until(lambda: screen.layer_data is not None
                        and screen.layer_data["cancelled"] == [], timeout=20)
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen))
            await pilot.press("down", "c")
            await until(lambda: any(t.startswith("body 1 cancelled") for t in texts(screen)),
                        what=lambda: texts(screen))

            await pilot.press("t")  # the estimate comes over MQTT before anything changes
            await until(lambda: isinstance(app.screen, RetuneScreen), timeout=30,
                        what=lambda: texts(screen))
            await pilot.press(*["backspace"] * 3, "4", "0", "enter", "enter", "enter", "enter")
            await until(lambda: isinstance(app.screen, ConfirmScreen), timeout=30,
                        what=lambda: texts(screen))
            question = str(app.screen.query_one("#question").render())
            assert "infill.density = 0.4" in question
            before, after = re.search(r"filament (\S+) m -> (\S+) m", question).groups()
            assert float(after) > float(before)  # denser infill: more filament
            assert re.search(r"ETA \d+:\d\d -> \d+:\d\d", question)
            await pilot.press("y")
            await until(lambda: "> set settings={'infill.density': 0.4}" in texts(screen),
                        what=lambda: texts(screen))
            await pilot.press("r")
            await until(lambda: screen.snapshot.state == "printing", timeout=20)
            assert not any(t.startswith("refused") for t in texts(screen)), texts(screen)
            await pilot.press("escape")
            await until(lambda: app.screen is fleet)
            assert source._replies == {}  # closed with its screen

    try:
        asyncio.run(scenario())
        done = folder / "jobs" / "done" / "pair.gcode"
        deadline = time.monotonic() + 240
        while not done.exists():
            assert daemon.poll() is None, "the daemon exited"
            assert time.monotonic() < deadline, "the job did not finish"
            time.sleep(0.1)
    finally:
        daemon.terminate()
        daemon.wait(timeout=20)
    summary = (folder / "jobs" / "done" / "pair.summary.txt").read_text()
    cancelled = int(re.search(r"body 1 cancelled from layer (\d+)", summary).group(1))
    retuned = int(re.search(r"from layer (\d+): \{'infill.density': 0.4\}", summary).group(1))
    assert "body 0" not in summary
    plan = SlicePlan.from_file(model, SliceSettings())
    dense = SlicePlan.from_file(model, SliceSettings.from_mapping({"infill.density": 0.4}))
    assert 0 < cancelled < plan.layer_count
    # the layers printed after the cancel leave body 1 out, those after the retune are denser
    expected = commands(plan.start_gcode())
    expected += layer_commands(lambda i: dense if i >= retuned else plan,
                               lambda i: frozenset({1}) if i >= cancelled else frozenset(),
                               plan.layer_count)
    expected += commands(dense.end_gcode())
    assert commands_of(done) == expected


def test_a_printer_without_commands_answers_requests_and_its_refusals_are_shown(
    tmp_path: Path, broker: Broker
) -> None:
    model = two_bodies(tmp_path / "pair.stl")
    folder = tmp_path / "d"
    # slow: it cannot be paused (commands are refused) and must print until the end
    daemon = start_daemon(folder, broker, "farm9", allow_commands=False, time_scale=0.05)
    source = MqttSource(HOST, broker.port, username=USER, password=SECRET)

    async def elsewhere() -> tuple[list[str], dict]:
        """A request whose reply topic is not farm9's: refused on its event topic."""
        async with aiomqtt.Client(HOST, broker.port, username=USER, password=SECRET) as client:
            await client.subscribe("elsewhere/#", qos=1)
            await client.subscribe("hostd/farm9/event", qos=1)
            await client.publish("hostd/farm9/req", json.dumps(
                {"req": "layer", "id": "x1", "reply_to": "elsewhere/inbox"}), qos=1)
            seen: list[str] = []
            async with asyncio.timeout(20):
                async for message in client.messages:
                    seen.append(str(message.topic))
                    if str(message.topic) == "hostd/farm9/event":
                        event = json.loads(message.payload)
                        if event.get("id") == "x1":
                            return seen, event
        raise AssertionError("unreachable")

    async def scenario() -> None:
        app = FleetApp(source, refresh_s=0.05)
        async with app.run_test(size=(120, 40)) as pilot:
            await until(lambda: rows(app) == [("farm9", "idle")], timeout=40,
                        what=lambda: rows(app))
            drop(folder, model)
            # requests change nothing: the picture comes without allow_commands
            screen = await open_printing(app, pilot, "farm9")
            assert screen.layer_data["body_count"] == 2
            await pilot.press("o")
            await until(lambda: isinstance(app.screen, ObjectsScreen))
            await pilot.press("c")
            await until(lambda: "refused cancel_object: commands are disabled "
                                "(mqtt.allow_commands = false)" in texts(screen),
                        what=lambda: texts(screen))
            await pilot.press("t")
            await until(lambda: isinstance(app.screen, RetuneScreen), timeout=30,
                        what=lambda: texts(screen))
            await pilot.press(*["backspace"] * 3, "5", "0", "enter", "enter", "enter", "enter")
            await until(lambda: isinstance(app.screen, ConfirmScreen), timeout=30,
                        what=lambda: (app.screen, texts(screen)))
            await pilot.press("y")
            await until(lambda: any(t.startswith("refused set: commands are disabled")
                                    for t in texts(screen)), what=lambda: texts(screen))

            seen, event = await elsewhere()
            assert event["event"] == "error"
            assert "hostd/farm9/reply/<client>" in event["reason"]
            assert not any(topic.startswith("elsewhere/") for topic in seen)

            # a printer that does not answer: a clear message, not a hang
            source.query_timeout = 0.5
            with pytest.raises(ControlError, match=r"no reply from nobody in 0\.5 s"):
                await source.query("nobody", "layer")
            await pilot.press("escape")

    try:
        asyncio.run(scenario())
    finally:
        daemon.terminate()
        daemon.wait(timeout=20)
