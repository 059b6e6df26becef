"""The dashboard on a fixed source: layout at 80x24, panels, keys, and a source without replies."""

from __future__ import annotations

import asyncio
import tempfile
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
from support.doubles import RecordingController
from support.tui_helpers import EVENTS, T0, FixedSource, history, printing
from support.waiting import until
from textual.widgets._footer import FooterKey

from hostd.api import (
    ControlError,
    Snapshot,
    bar,
    duration,
)
from hostd.publishing.control import serve_control
from hostd.publishing.status import StatusHub
from tui.app import Dashboard
from tui.canvas import Canvas, Frame
from tui.format import clock, fit_words, layer_text
from tui.printer_screen import NO_LAYER_VIEW
from tui.sources import EventItem, SocketSource, StatusItem
from tui.widgets.dialogs import ConfirmScreen, FilterScreen, HelpScreen, RetuneScreen
from tui.widgets.eventlog import EventLog
from tui.widgets.layer import LayerView


def test_text_helpers() -> None:
    assert layer_text(0, 25) == "layer 1 of 25"
    assert layer_text(24, 25) == "layer 25 of 25"
    assert duration(None) == "--"
    assert duration(103) == "1:43"
    assert duration(3725) == "1:02:05"
    for fraction in (0.0, 0.33, 0.5, 1.0):
        assert len(bar(fraction, 17)) == 17
    assert bar(0.5, 10).startswith("█████")
    assert bar(1.0, 4) == "████"


def test_canvas_draws_a_square_where_it_belongs() -> None:
    frame = Frame((0, 0, 10, 10), cols=10, rows=5, margin=0)
    canvas = Canvas(10, 5)
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], dtype=float)
    canvas.polylines([frame.dots(square)], colour=3)
    codes = canvas.codes()
    assert codes.shape == (5, 10)
    lit = codes != 0x2800
    # 20 x 20 dots show a 10 mm square 20 dots wide, centred: columns 0..9 of rows 0..4
    assert lit[:, :].any(axis=0).tolist().count(True) == 10
    assert not lit[1:-1, 1:-1].any()  # hollow
    assert set(canvas.fg[lit].tolist()) == {3}
    text = canvas.text([None, None, None, __import__("rich.style").style.Style(color="red")])
    assert text.plain.count("\n") == 4
    assert len(text.plain.split("\n")[0]) == 10


def test_screen_at_80x24_shows_every_panel_without_wrapping() -> None:
    source = FixedSource()

    async def scenario() -> None:
        app = Dashboard(source)
        async with app.run_test(size=(80, 24)):
            screen = app.printer_screen
            await until(lambda: screen.layer_data is not None and len(screen.events) == 13)
            await until(lambda: screen.query_one(LayerView).printed is not None)
            job = [t.plain for t in screen.query_one("#job").render().renderables]
            width = screen.query_one("#job").content_size.width
            assert job[0].startswith("dogbone.stl")
            assert job[1].startswith("layer 13 of 25")
            assert job[2] == "elapsed 1:35  ETA 1:43  ahead 3"
            assert job[3] == "filament ≈1.21 of 2.53 m"
            assert all(len(line) <= width for line in job), (job, width)
            temps = screen.query_one("#temps").render().renderables[0].plain
            assert temps == "hotend 209.5/210°C  bed 59.8/60°C"
            queue = [t.plain for t in screen.query_one("#queue").render().renderables]
            assert queue[:2] == ["1. bracket.stl", "2. gear.stl"]
            assert queue[2] == "bunny.stl  stopped after layer 41"
            assert screen.query_one("#layer").border_title == "layer 13 of 25 · z 2.60 mm"
            view = screen.query_one(LayerView)
            assert 0 < view.printed_paths() < len(screen.layer_data["paths"])
            lines = view.picture().split("\n")
            assert len(lines) == view.content_size.height - 1
            assert {len(line) for line in lines} == {view.content_size.width}
            for widget in screen.query("#job, #temps, #queue, #layer, #log"):
                assert widget.region.right <= 80
                assert widget.region.bottom <= 23

    asyncio.run(scenario())
    layer_args = [args for cmd, args in source.queries if cmd == "layer"]
    assert layer_args
    assert all(args["layer"] == 12 for args in layer_args)


def test_fit_words_cuts_after_a_whole_word() -> None:
    assert fit_words("hotend heating", 20) == "hotend heating"
    assert fit_words("refused pause: no job is printing", 20) == "refused pause: no…"
    assert fit_words("refused pause: no job is printing", 19) == "refused pause: no…"
    assert fit_words("refused pause: no job is printing", 17) == "refused pause:…"
    assert fit_words("thermistor", 6) == "therm…"  # one word too long: cut where it must be
    assert fit_words("a b", 1) == "…"
    assert fit_words("a b", 0) == ""
    for width in range(1, 40):
        assert len(fit_words("refused pause: no job is printing", width)) <= width


REFUSAL = "thermal runaway: check the thermistor wiring"


def test_a_long_event_takes_one_line_cut_at_a_word_at_80x24() -> None:
    refused = EventItem("sim", {"event": "error", "cmd": "resume", "reason": REFUSAL, "ts": T0})
    source = FixedSource([*history(), *EVENTS, refused])
    whole = f"{clock(T0)} refused resume: {REFUSAL}"

    def shown(log: EventLog) -> list[str]:
        return [strip.text for strip in log.lines]

    async def scenario() -> None:
        app = Dashboard(source)
        async with app.run_test(size=(80, 24)) as pilot:
            screen = app.printer_screen
            log = screen.query_one(EventLog)
            await until(lambda: len(log.lines) == 14)
            width = log.line_width()
            assert 30 <= width < len(whole)
            lines = shown(log)
            assert len(lines) == len(log.entries) == 14  # one line each: nothing wraps
            assert all(len(line.rstrip()) <= width for line in lines), lines
            assert log.virtual_size.width <= width  # nothing to scroll sideways either
            for line, (ts, _colour, text) in zip(lines, log.entries, strict=True):
                full, line = f"{clock(ts)} {text}", line.rstrip()
                if line != full:  # cut: after a whole word, with an ellipsis
                    assert line.endswith("…"), line
                    assert full.startswith(line[:-1]), line
                    assert full[len(line) - 1] == " ", line
            assert lines[-1].rstrip() != whole
            # a word cut off is still found by the filter, in the whole text
            await pilot.press("slash", *"thermistor", "enter")
            await until(lambda: screen.log_filter == "thermistor")
            assert len(log.lines) == 1
            assert shown(log)[0].startswith(f"{clock(T0)} refused")
            await pilot.press("slash", *["backspace"] * 10, "enter")
            await until(lambda: screen.log_filter == "" and len(log.lines) == 14)
            assert not isinstance(app.screen, FilterScreen)
            # a wider terminal lays the lines out again: the whole refusal shows
            await pilot.resize_terminal(200, 40)
            await until(lambda: log.line_width() >= len(whole))
            await until(lambda: shown(log)[-1].rstrip() == whole)
            assert len(log.lines) == 14
            await pilot.resize_terminal(80, 24)
            await until(lambda: log.line_width() == width and shown(log) == lines)

    asyncio.run(scenario())


def test_keys_pause_resume_confirmed_cancel_and_emergency_stop_filter_retune() -> None:
    source = FixedSource(refuse=("resume",))

    async def scenario() -> None:
        app = Dashboard(source)
        async with app.run_test(size=(100, 30)) as pilot:
            screen = app.printer_screen
            await until(lambda: screen.layer_data is not None)
            await pilot.press("p")
            await until(lambda: ("pause", {}) in source.calls)
            await pilot.press("r")
            await until(lambda: any("resume refused" in e[2] for e in screen.events))
            await pilot.press("c")
            await until(lambda: isinstance(app.screen, ConfirmScreen))
            await pilot.press("n")
            await pilot.pause()
            assert all(cmd != "cancel" for cmd, _ in source.calls)
            await pilot.press("c", "y")
            await until(lambda: ("cancel", {}) in source.calls)
            await pilot.press("exclamation_mark")  # emergency stop: asks first
            await until(lambda: isinstance(app.screen, ConfirmScreen))
            assert "M112" in str(app.screen.query_one("#question").render())
            await pilot.press("n")
            await pilot.pause()
            assert all(cmd != "emergency_stop" for cmd, _ in source.calls)
            await pilot.press("exclamation_mark", "y")
            await until(lambda: ("emergency_stop", {}) in source.calls)
            await pilot.press("R")
            await until(lambda: ("resume_job", {"job": "5"}) in source.calls)
            await pilot.press("slash", *"layer 3", "enter")
            await until(lambda: screen.log_filter == "layer 3")
            assert len(screen.query_one("#log").lines) == 1  # "layer 3 of 25 done"
            await pilot.press("t")
            await until(lambda: isinstance(app.screen, RetuneScreen))
            await pilot.press(*["backspace"] * 3, "4", "0", "enter", "enter", "enter", "enter")
            await until(lambda: isinstance(app.screen, ConfirmScreen))
            question = str(app.screen.query_one("#question").render())
            assert "infill.density = 0.4" in question
            assert "ETA 1:43 -> 2:11" in question
            assert "2.53 m -> 3.10 m" in question
            await pilot.press("y")
            await until(lambda: ("set", {"settings": {"infill.density": 0.4}}) in source.calls)
            help_key = next(k for k in screen.query(FooterKey) if k.key == "question_mark")
            await pilot.click(help_key)  # the mouse works the footer's keys
            await until(lambda: isinstance(app.screen, HelpScreen))
            await pilot.press("escape", "q")
        assert not app.is_running

    asyncio.run(scenario())
    retune = [args for cmd, args in source.queries if cmd == "estimate" and args]
    assert retune == [{"settings": {"infill.density": 0.4}}]


class StatusOnly:
    """A source like MQTT: status and commands, no replies to read (no ``query``)."""

    label = "status only"

    async def stream(self) -> AsyncIterator[StatusItem]:
        yield StatusItem("a", printing(T0))
        yield StatusItem("b", Snapshot(state="error", error="thermal runaway", ts=T0))
        await asyncio.Event().wait()

    async def command(self, printer: str, cmd: str, **args: Any) -> None:
        raise ControlError("commands are disabled")


def test_a_source_without_replies_shows_status_and_says_why_there_is_no_picture() -> None:
    async def scenario() -> None:
        app = Dashboard(StatusOnly(), printer="a")
        async with app.run_test(size=(80, 24)) as pilot:
            screen = app.printer_screen
            await until(lambda: screen.query_one(LayerView).message == NO_LAYER_VIEW)
            assert screen.snapshot.state == "printing"  # printer b's error is not this one's
            await pilot.press("p")
            await until(lambda: any("pause refused: commands are disabled" in e[2]
                                    for e in screen.events))

    asyncio.run(scenario())


def test_socket_source_status_and_commands_over_a_real_control_socket() -> None:
    async def scenario(folder: Path) -> RecordingController:
        hub = StatusHub(Snapshot(state="idle"))
        controller = RecordingController({"layer": "no job is printing"})
        path = folder / "hostd.sock"
        server = asyncio.create_task(serve_control(path, hub, controller))
        await until(path.exists)
        app = Dashboard(SocketSource(str(path)))
        async with app.run_test(size=(80, 24)) as pilot:
            screen = app.printer_screen
            await until(lambda: screen.snapshot.state == "idle")
            hub.update(state="printing", job=printing(T0).job)
            await until(lambda: screen.query_one(LayerView).message == "no job is printing")
            hub.event("layer", id="7", layer=3, layers=25)
            await until(lambda: any(e[2] == "layer 4 of 25 done" for e in screen.events))
            await pilot.press("p")
            await until(lambda: ("pause", {}) in controller.calls)
        server.cancel()
        await asyncio.gather(server, return_exceptions=True)
        return controller

    with tempfile.TemporaryDirectory(prefix="hostd-tui-") as folder:
        controller = asyncio.run(scenario(Path(folder)))
    assert [cmd for cmd, _ in controller.calls if cmd != "estimate"][-1] == "pause"
