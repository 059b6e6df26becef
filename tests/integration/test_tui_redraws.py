"""What the dashboard redraws: only what changed, and the picture's progress at a bounded rate.

Counted, not timed: the cells each widget asks to repaint (``LinesWidget``'s
counters), its ``refresh`` calls, and the layer picture's redraws against an
injected clock. ``tests/test_tui_terminal.py`` checks that these partial
updates leave the terminal right.
"""

from __future__ import annotations

import asyncio
import dataclasses
from typing import Any

import numpy as np
import pytest
from rich.style import Style
from rich.text import Text
from support.tui_helpers import T0, FixedSource, printing
from support.waiting import until
from textual.widget import Widget

from hostd.app.cli import main
from tui.app import Dashboard, redraw_seconds
from tui.fleet_model import COLUMNS
from tui.fleet_table import changed_columns, column_widths
from tui.sources import StatusItem
from tui.widgets.eventlog import EventLog
from tui.widgets.layer import LayerView
from tui.widgets.lines import MERGE_GAP, changed_cells, changed_runs
from tui.widgets.panels import JobPanel, TempPanel

RED, GREEN = Style(color="red"), Style(color="green")


def test_changed_cells_are_the_runs_that_differ() -> None:
    same = Text("elapsed 1:35  ETA 1:43")
    assert changed_cells(same, Text("elapsed 1:35  ETA 1:43"), 40) == []
    assert changed_cells(same, Text("elapsed 1:36  ETA 1:43"), 40) == [(11, 1)]
    far = changed_cells(same, Text("elapsed 1:36  ETA 1:42"), 40)
    assert far == [(11, 1), (21, 1)]  # 9 cells apart: two runs
    assert changed_cells(Text("ab--------"), Text("xb---y----"), 40) == [(0, 6)]  # joined
    assert 21 - 11 > MERGE_GAP >= 6 - 1
    # a colour changes, not a character: that cell
    old = Text.assemble(("⣿⣿", RED), ("⣿⣿", RED))
    new = Text.assemble(("⣿⣿", RED), ("⣿", GREEN), ("⣿", RED))
    assert changed_cells(old, new, 40) == [(2, 1)]
    # a shorter text clears the cells it no longer covers
    assert changed_cells(Text("100%"), Text("9%"), 40) == [(0, 4)]
    # cut with an ellipsis at the row's end: from the change to the end of the row
    assert changed_cells(Text("a" * 30 + "b"), Text("a" * 20 + "c" * 11), 25) == [(20, 5)]
    # wide characters: the whole row
    assert changed_cells(Text("部品 a"), Text("部品 b"), 10) == [(0, 10)]


def test_changed_runs_of_rows() -> None:
    rows = [Text(c) for c in "abcdef"]
    assert list(changed_runs(rows, rows)) == []
    changed = [Text(c) for c in "aXcYZf"]
    assert list(changed_runs(rows, changed)) == [(1, 1), (3, 2)]
    assert list(changed_runs(rows[:2], rows)) == [(2, 4)]  # new rows at the end


def test_a_fleet_row_repaints_only_the_columns_that_changed() -> None:
    old = ("farm-01", "printing", "part-01", "███▌     44%", "92/209", "11:48", "209/210", "60/60")
    new = (*old[:6], "210/210", old[7])
    widths = column_widths(80)
    hotend = [key for key, _, _ in COLUMNS].index("hotend")
    x = 1 + sum(w + 1 for w in widths[:hotend])
    assert changed_columns(old, new, 80) == [(x, widths[hotend])]
    assert changed_columns(old, old, 80) == []
    moved = ("farm-01", "error", *old[2:])
    assert changed_columns(old, moved, 80) == [(1 + widths[0] + 1, widths[1])]


def counted(widget: Any) -> list[tuple]:
    """Record the regions of every ``refresh`` call of ``widget`` (and still refresh)."""
    calls: list[tuple] = []
    refresh = widget.refresh

    def recording(*regions: Any, **kwargs: Any) -> Any:
        calls.append(regions)
        return refresh(*regions, **kwargs)

    widget.refresh = recording
    return calls


async def _ready(app: Dashboard) -> tuple[Any, LayerView]:
    screen = app.printer_screen
    await until(lambda: screen.layer_data is not None and len(screen.events) == 13)
    view = screen.query_one(LayerView)
    await until(lambda: view.printed is not None and view.drawn_paths == view.printed_paths())
    return screen, view


def _lines_for_paths(screen: Any, paths: int) -> int:
    """``lines_acked`` at which exactly ``paths`` paths of the shown layer are printed."""
    data = screen.layer_data
    return data["acked_before"] + data["paths"][paths - 1]["end"]


def test_a_status_that_changes_nothing_visible_repaints_no_picture() -> None:
    async def scenario() -> None:
        app = Dashboard(FixedSource())
        async with app.run_test(size=(80, 24)) as pilot:
            screen, view = await _ready(app)
            job, temps = screen.query_one(JobPanel), screen.query_one(TempPanel)
            calls = counted(view)
            cells = view.repainted_cells
            # the same acknowledged lines again (a newer status): nothing of the picture
            screen.feed(_status(T0 + 0.5, 2400))
            await pilot.pause()
            assert calls == []
            assert view.repainted_cells == cells
            # one more line acknowledged that completes no path: still nothing
            done = view.printed_paths()
            lines = _lines_for_paths(screen, done + 1) - 1
            assert lines > 2400  # the fixed story's status is inside a path
            screen.feed(_status(T0 + 0.6, lines))
            await pilot.pause()
            assert view.printed == lines - screen.layer_data["acked_before"]
            assert view.printed_paths() == done
            assert calls == []
            # the elapsed time alone moves: a few cells of one row of the job panel
            before = job.repainted_cells
            snap = printing(T0 + 0.7)
            screen.feed(StatusItem("sim", dataclasses.replace(
                snap, job=dataclasses.replace(snap.job, elapsed_s=96.0))))
            await pilot.pause()
            assert 0 < job.repainted_cells - before <= 4
            # temperatures a tenth of a degree apart: the numbers, not the chart
            before = temps.repainted_cells
            screen.feed(StatusItem("sim", printing(T0 + 0.8, hotend=209.6)))
            await pilot.pause()
            assert 0 < temps.repainted_cells - before <= 8

    asyncio.run(scenario())


def _status(ts: float, lines: int) -> StatusItem:
    return StatusItem("sim", printing(ts, lines=lines))


def test_a_path_turning_bright_repaints_part_of_the_picture_at_most_once_a_second() -> None:
    now = [0.0]

    async def scenario() -> None:
        app = Dashboard(FixedSource())
        async with app.run_test(size=(120, 40)) as pilot:
            screen, view = await _ready(app)
            now[0] = view.clock() + 5.0  # long after the last drawing
            view.clock = lambda: now[0]
            view.progress_s = 1.0
            size = view.content_size
            done = view.printed_paths()
            paths = len(screen.layer_data["paths"])
            assert done + 3 < paths
            # a path turns bright: drawn at once, only the cells it changes
            cells = view.repainted_cells
            screen.feed(_status(T0 + 1, _lines_for_paths(screen, done + 1)))
            await pilot.pause()
            assert view.drawn_paths == done + 1
            assert 0 < view.repainted_cells - cells < size.width * size.height // 2
            drawn = view.content_lines(size.width, size.height)  # with its colours
            # two more within the same second: held back, the picture unchanged
            now[0] += 0.4
            screen.feed(_status(T0 + 1.4, _lines_for_paths(screen, done + 2)))
            now[0] += 0.4
            screen.feed(_status(T0 + 1.8, _lines_for_paths(screen, done + 3)))
            await pilot.pause()
            assert view.drawn_paths == done + 1
            assert view.content_lines(size.width, size.height) == drawn
            assert view.printed_paths() == done + 3
            # its timer draws the last value: nothing acknowledged is lost
            await until(lambda: view.drawn_paths == done + 3)
            assert view.content_lines(size.width, size.height) != drawn
            # a second later on the clock the next path is drawn at once again
            now[0] += 1.0
            screen.feed(_status(T0 + 3, screen.layer_data["acked_before"]
                                + screen.layer_data["commands"]))
            await pilot.pause()
            assert view.drawn_paths == paths
            assert np.searchsorted([p["end"] for p in screen.layer_data["paths"]],
                                   screen.layer_data["commands"], side="right") == paths

    asyncio.run(scenario())


def test_a_new_layer_title_repaints_only_the_border_row(monkeypatch: Any) -> None:
    async def scenario() -> None:
        app = Dashboard(FixedSource())
        async with app.run_test(size=(80, 24)) as pilot:
            _screen, view = await _ready(app)
            calls: list[tuple] = []
            refresh = Widget.refresh

            def recording(self: Widget, *regions: Any, **kwargs: Any) -> Any:
                if self is view:
                    calls.append(regions)
                return refresh(self, *regions, **kwargs)

            monkeypatch.setattr(Widget, "refresh", recording)  # what reaches Textual
            view.set_border_title(view.border_title or "")
            assert calls == []  # the same title: nothing
            view.set_border_title("layer 14 of 25 · z 2.80 mm")
            assert len(calls) == 1
            assert len(calls[0]) == 1
            (region,) = calls[0]
            assert region.height == 1
            assert region.y == -view.content_offset.y
            assert region.width == view.outer_size.width
            await pilot.pause()
            assert view.border_title == "layer 14 of 25 · z 2.80 mm"

    asyncio.run(scenario())


def test_the_slow_link_setting_holds_new_layers_and_log_lines_back() -> None:
    now = [0.0]

    async def scenario() -> None:
        app = Dashboard(FixedSource(), redraw_s=0.5)
        async with app.run_test(size=(80, 24)) as pilot:
            screen, view = await _ready(app)
            log = screen.query_one(EventLog)
            assert (view.layer_s, view.progress_s, log.batch_s) == (0.5, 1.0, 0.5)
            now[0] = view.clock()  # the first layer was just drawn
            view.clock = lambda: now[0]
            first, title = view.drawn, view.border_title
            other = {**screen.layer_data, "layer": 13, "z": 2.8}
            view.show(other)  # a new layer within 0.5 s of the last drawing: held
            await pilot.pause()
            assert view.drawn is first
            assert view.border_title == title  # the title goes with the picture
            await until(lambda: view.drawn is other)
            assert view.border_title == "layer 14 of 25 · z 2.80 mm"
            # two events within the batch: shown together, none lost
            lines = len(log.lines)
            screen.add_event({"event": "layer", "id": "7", "layer": 12, "layers": 25, "ts": T0})
            screen.add_event({"event": "layer", "id": "7", "layer": 13, "layers": 25, "ts": T0})
            await pilot.pause()
            assert len(log.lines) == lines
            await until(lambda: len(log.lines) == lines + 2)
            assert len(log.entries) == lines + 2

    asyncio.run(scenario())


def test_the_slow_link_setting_is_read_and_checked(monkeypatch: Any,
                                                    capsys: Any) -> None:
    monkeypatch.delenv("HOSTD_TUI_REDRAW_S", raising=False)
    assert redraw_seconds() == 0.0
    assert redraw_seconds("5") == 5.0
    monkeypatch.setenv("HOSTD_TUI_REDRAW_S", "2.5")
    assert redraw_seconds() == 2.5
    assert redraw_seconds("0") == 0.0  # the option wins over the environment
    for bad in ("-1", "soon", "nan", "inf"):
        with pytest.raises(ValueError, match=r"seconds|float"):
            redraw_seconds(bad)
    assert main(["tui", "--redraw-s", "-1", "--socket", "/nonexistent"]) == 2
    assert "--redraw-s (or $HOSTD_TUI_REDRAW_S)" in capsys.readouterr().err
    monkeypatch.setenv("HOSTD_TUI_REDRAW_S", "soon")
    assert main(["tui", "--mqtt", "farm"]) == 2
    assert "could not convert" in capsys.readouterr().err
