"""The fleet view against a real mosquitto: synthetic printers, a last will, counts, filter."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.brokers import HOST, Broker, free_port, start_broker
from support.fleet_helpers import REPO, rows
from support.waiting import until
from textual.widgets import Static

from tui.fleet import FleetApp, FleetScreen
from tui.fleet_model import RANKS
from tui.sources import MqttSource

# index % 6 -> state, for the twelve printers p0000..p0011
STATES = "printing,idle,paused,error,printing,heating"


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    running = start_broker(tmp_path / "broker")
    yield running
    running.stop()


def publisher(broker: Broker, *args: str) -> subprocess.Popen[bytes]:
    """Synthetic printers publishing their status once (retained), connections kept open."""
    return subprocess.Popen(
        [sys.executable, "-m", "bench.fleetpub", "--broker", f"{HOST}:{broker.port}",
         "--prefix", "p", "--rate", "0", "--hold", "120", *args],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )


def counts_line(app: FleetApp) -> str:
    return str(app.screen.query_one("#counts", Static).render())


@pytest.mark.parametrize("size", [(80, 24), (160, 50)])
def test_fleet_sorts_problems_first_shows_a_lost_printer_offline_and_filters(
    broker: Broker, size: tuple[int, int]
) -> None:
    many = publisher(broker, "--count", "12", "--states", STATES)
    doomed = publisher(broker, "--count", "1", "--first", "50", "--will", "--states", "printing")

    async def scenario() -> None:
        app = FleetApp(MqttSource(HOST, broker.port), refresh_s=0.05)
        async with app.run_test(size=size) as pilot:
            assert isinstance(app.screen, FleetScreen)
            await until(lambda: len(rows(app)) == 13)
            await until(lambda: dict(rows(app)).get("p0050") == "printing")
            # every printer's own status in (retained ones of an earlier run may come first)
            await until(lambda: [state for _, state in rows(app)][:2] == ["error", "error"],
                        what=lambda: rows(app))
            states = [state for _, state in rows(app)]
            assert [RANKS[s] for s in states] == sorted(RANKS[s] for s in states)
            await until(lambda: "printing 5" in counts_line(app) and "error 2" in counts_line(app),
                        what=lambda: counts_line(app))

            doomed.kill()  # its TCP connection drops: the broker publishes its last will
            doomed.wait(timeout=10)
            await until(lambda: dict(rows(app)).get("p0050") == "offline")
            order = rows(app)
            assert [state for _, state in order[:3]] == ["error", "error", "offline"]
            assert order[2][0] == "p0050"
            assert "offline 1" in counts_line(app)
            assert "printing 4" in counts_line(app)

            await pilot.press("slash", *"paus")
            await until(lambda: len(rows(app)) == 2)
            assert {state for _, state in rows(app)} == {"paused"}
            assert "2" in counts_line(app)
            assert "shown" in counts_line(app)
            await pilot.press("escape")
            await until(lambda: len(rows(app)) == 13)

            await pilot.press("slash", *"p0050", "enter")
            await until(lambda: rows(app) == [("p0050", "offline")])
            await pilot.press("escape")
            await until(lambda: len(rows(app)) == 13)

    try:
        asyncio.run(scenario())
    finally:
        for proc in (many, doomed):
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=10)


def start_daemon(folder: Path, broker: Broker, printer: str, user: str, secret: str,
                 hosts: str = "") -> subprocess.Popen[bytes]:
    """`hostd run` on the simulated printer, bridged to ``broker`` with commands allowed."""
    folder.mkdir(parents=True, exist_ok=True)
    where = f"hosts = [{hosts}]\n" if hosts else f"host = \"{HOST}\"\nport = {broker.port}\n"
    (folder / "hostd.toml").write_text(
        "[jobs]\nfolder = \"jobs\"\nsettle_s = 0.2\n[state]\nfolder = \"var\"\n"
        f"[printer]\nid = \"{printer}\"\n[simulator]\ntime_scale = 0\nbaud = 0\n"
        f"[mqtt]\nenabled = true\n{where}username = \"{user}\"\npassword = \"{secret}\"\n"
        "allow_commands = true\n"
    )
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())",
         "run", "--config", str(folder / "hostd.toml")],
        cwd=folder, env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )


def test_enter_opens_the_printer_screen_over_mqtt_refusal_emergency_stop_and_back(
    tmp_path: Path
) -> None:
    from support.gcode_lines import executed_job_lines

    from tui.printer_screen import PrinterScreen
    from tui.widgets.dialogs import ConfirmScreen
    from tui.widgets.layer import LayerView

    broker = start_broker(tmp_path / "broker", users={"farm": "pw-9"})
    daemon = start_daemon(tmp_path / "d", broker, "farm7", "farm", "pw-9")
    executed = tmp_path / "d" / "var" / "simulator-executed.log"

    def texts(screen: PrinterScreen) -> list[str]:
        return [text for _ts, _colour, text in screen.events]

    async def scenario() -> None:
        nobody = (HOST, free_port())  # a dead node first: the view goes on to the next
        source = MqttSource([nobody, (HOST, broker.port)], username="farm", password="pw-9")
        app = FleetApp(source, refresh_s=0.05)
        async with app.run_test(size=(80, 24)) as pilot:
            await until(lambda: rows(app) == [("farm7", "idle")], timeout=40,
                        what=lambda: (rows(app), app.screen.note, source.connected_to))
            fleet = app.screen
            await pilot.press("enter")
            await until(lambda: isinstance(app.screen, PrinterScreen))
            screen = app.screen
            assert isinstance(screen, PrinterScreen)
            assert screen.printer == "farm7"
            assert not screen.own_stream  # fed by the fleet's one connection
            # the last status the fleet heard is shown at once (an idle daemon is quiet)
            assert screen.snapshot.state == "idle"
            assert screen.snapshot.printer.connected
            bar = str(screen.query_one("#state").render())
            assert "farm7" in bar
            assert "IDLE" in bar.upper()
            assert "no job printing" in str(screen.query_one(LayerView).render())
            await pilot.pause()  # the screen takes keys once it is mounted
            await pilot.press("p")  # nothing is printing: the daemon refuses on its event topic
            await until(lambda: "> pause" in texts(screen), what=lambda: texts(screen))
            await until(lambda: "refused pause: no job is printing" in texts(screen),
                        what=lambda: texts(screen))
            await pilot.press("exclamation_mark")
            await until(lambda: isinstance(app.screen, ConfirmScreen))
            assert "M112" in str(app.screen.query_one("#question").render())
            await pilot.press("y")
            await until(lambda: executed_job_lines(executed)[-1:] == ["M112"],
                        what=lambda: (texts(screen), executed.read_text()[-200:]))
            assert "> emergency_stop" in texts(screen)
            await pilot.press("escape")
            await until(lambda: app.screen is fleet)
            await until(lambda: fleet.opened is None)
            await pilot.press("enter", "q")  # q goes back too, and never quits from there
            await until(lambda: app.screen is fleet)
            assert app.is_running

    try:
        asyncio.run(scenario())
    finally:
        daemon.kill()
        daemon.wait(timeout=10)
        broker.stop()
