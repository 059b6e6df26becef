"""The dashboard driven by Textual's Pilot against a real control socket."""

from __future__ import annotations

import asyncio
import tempfile
from pathlib import Path

from doubles import RecordingController
from textual.widgets import ProgressBar, RichLog, Static

from hostd.api import InterruptedJob, JobStatus, Snapshot, Temperature, Temps
from hostd.control import serve_control
from hostd.status import StatusHub
from tui.app import Dashboard, describe_job, describe_queue
from tui.sources import SocketSource

PRINTING = Snapshot(
    state="printing",
    temps=Temps(hotend=Temperature(209.5, 210.0), bed=Temperature(59.8, 60.0)),
    job=JobStatus(id="7", name="dogbone", layer=12, layers=25, progress=0.48, lines_acked=4321,
                  elapsed_s=95.0, eta_s=103.0, layers_ready_ahead=3),
    queue=("bracket", "gear"),
    interrupted=(InterruptedJob(id="5", name="bunny", layer=40),),
)


def _text(app: Dashboard, selector: str) -> str:
    return str(app.query_one(selector, Static).render())


async def _until(predicate, timeout: float = 5.0) -> None:
    deadline = asyncio.get_running_loop().time() + timeout
    while not predicate():
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.02)


async def _scenario(folder: Path) -> RecordingController:
    hub = StatusHub(Snapshot(state="idle"))
    controller = RecordingController({"resume": "nothing is paused"})
    path = folder / "hostd.sock"
    server = asyncio.create_task(serve_control(path, hub, controller), name="control")
    await _until(path.exists)
    app = Dashboard(SocketSource(str(path)))
    async with app.run_test(size=(110, 30)) as pilot:
        await _until(lambda: "No job" in _text(app, "#job"))
        hub.update(**{k: getattr(PRINTING, k) for k in ("state", "temps", "job", "queue",
                                                          "interrupted")})
        await _until(lambda: "dogbone" in _text(app, "#job"))
        assert "layer 12/25" in _text(app, "#job")
        assert "209.5" in _text(app, "#temps")
        assert "bracket" in _text(app, "#queue_text") and "bunny" in _text(app, "#queue_text")
        assert abs(app.query_one("#progress", ProgressBar).progress - 0.48) < 1e-9
        assert "PRINTING" in app.title

        hub.event("layer", layer=12)
        await _until(lambda: len(app.query_one("#log", RichLog).lines) >= 1)

        await pilot.press("p")
        await _until(lambda: ("pause", {}) in controller.calls)
        await pilot.press("r")
        await _until(lambda: any(c == "resume" for c, _ in controller.calls))
        await _until(lambda: any("refused" in str(line) for line in app.query_one("#log",
                                                                                  RichLog).lines))
        await pilot.press("c")
        await asyncio.sleep(0.2)
        assert all(c != "cancel" for c, _ in controller.calls), "one press must not cancel"
        await pilot.press("c")
        await _until(lambda: any(c == "cancel" for c, _ in controller.calls))
        await pilot.press("R")
        await _until(lambda: ("resume_job", {"job": "5"}) in controller.calls)
    server.cancel()
    await asyncio.gather(server, return_exceptions=True)
    return controller


def test_dashboard_shows_status_and_sends_commands() -> None:
    with tempfile.TemporaryDirectory(prefix="hostd-tui-") as folder:
        controller = asyncio.run(_scenario(Path(folder)))
    assert [cmd for cmd, _ in controller.calls] == ["pause", "resume", "cancel", "resume_job"]


def test_panel_texts() -> None:
    assert "No job" in describe_job(Snapshot())
    text = describe_job(PRINTING)
    assert "lines acknowledged 4321" in text and "ETA 1:43" in text
    assert describe_queue(Snapshot()) == "(empty)"
