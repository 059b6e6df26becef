"""The live progress line (`make run` without a terminal, `hostd print`): never wider than
the terminal is at each redraw, however narrow."""

from __future__ import annotations

import fcntl
import io
import os
import pty
import struct
import termios

import pytest
from support.waiting import until

from hostd.api import JobStatus, Snapshot, Temperature, Temps
from hostd.app.commands.print_file import Progress, ProgressBar
from hostd.app.demo import progress_line
from hostd.app.liveline import LiveLine, terminal_columns

JOB = JobStatus(id="1", name="a_rather_long_file_name_for_a_part.stl", layer=41, layers=309,
                progress=0.136, lines_acked=123456, eta_s=4321.0)
SNAPSHOT = Snapshot(state="printing", job=JOB,
                    temps=Temps(hotend=Temperature(209.7, 210.0), bed=Temperature(59.9, 60.0)))


def set_columns(fd: int, columns: int) -> None:
    """Resize the pseudo-terminal (as a user narrowing the window does)."""
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))


def redraws(master: int) -> list[str]:
    """What reached the terminal since the last call, one item per ``\\r``-started redraw."""
    data = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except BlockingIOError:
            break
        if not chunk:
            break
        data += chunk
    return [part for part in data.decode().split("\r") if part]


@pytest.fixture
def terminal():
    """A pseudo-terminal: (the master to read and resize, the slave as a text stream)."""
    master, slave = pty.openpty()
    os.set_blocking(master, False)
    stream = os.fdopen(slave, "w", encoding="utf-8")
    yield master, stream
    stream.close()
    os.close(master)


def test_a_narrowed_terminal_never_gets_a_line_wider_than_it(terminal) -> None:
    master, stream = terminal
    line = LiveLine(stream)  # as the demo's watch() draws: the width read at every redraw
    for columns in (160, 100, 40, 19, 12, 5, 2, 1, 80):
        set_columns(master, columns)
        assert terminal_columns(stream) == columns
        line.draw(progress_line(SNAPSHOT, line.width() + 1))
        drawn = redraws(master)
        assert all(len(part) <= columns - 1 for part in drawn), (columns, drawn)  # padding too
        if columns > 1:
            assert len(drawn) == 1, columns
        if columns >= 100:
            assert "layer 42 of 309" in drawn[0]
    line.clear()
    assert all(len(part) <= 79 for part in redraws(master))


def test_hostd_print_follows_the_terminal_as_it_narrows(terminal) -> None:
    master, stream = terminal
    bar = ProgressBar(stream)
    progress = Progress("layers", 309, done=42, acked=41_500, hotend=(209.7, 210.0),
                        layer_ends=[1000 * (k + 1) for k in range(42)])
    for columns in (120, 30, 15, 3):
        set_columns(master, columns)
        bar.draw(progress, final=True)
        drawn = [part.rstrip("\n") for part in redraws(master)]
        assert drawn, columns
        assert all(len(part) <= columns - 1 for part in drawn), (columns, drawn)
    assert terminal_columns(stream) == 3


def test_under_20_columns_without_a_terminal(monkeypatch) -> None:
    for columns in (1, 2, 7, 12, 19):
        monkeypatch.setenv("COLUMNS", str(columns))
        out = io.StringIO()
        line = LiveLine(out)
        assert line.width() == columns - 1
        line.draw(progress_line(SNAPSHOT, line.width() + 1))
        line.draw("x" * 300)
        line.clear()
        assert all(len(part) <= columns - 1 for part in out.getvalue().split("\r")), columns
        assert len(progress_line(SNAPSHOT, columns)) <= columns - 1


def test_a_terminal_that_reports_no_width_falls_back(terminal, monkeypatch) -> None:
    master, stream = terminal
    set_columns(master, 0)  # some pseudo-terminals say 0: unknown
    monkeypatch.setenv("COLUMNS", "33")
    assert terminal_columns(stream) == 33
    monkeypatch.delenv("COLUMNS")
    assert terminal_columns(stream) >= 1


def test_the_demo_line_follows_a_terminal_narrowed_while_it_prints(terminal, tmp_path,
                                                                   monkeypatch) -> None:
    """`make run` without the dashboard: its status line over a real control socket, the
    terminal narrowed between two statuses (the line used to keep the old width)."""
    import asyncio
    import dataclasses
    import sys

    from support.doubles import RecordingController

    from hostd.app import demo
    from hostd.publishing.control import serve_control
    from hostd.publishing.status import StatusHub

    master, stream = terminal
    monkeypatch.setattr(sys, "stdout", stream)

    class Running:
        """The demo's daemon, as far as watch() asks: still running."""

        def poll(self) -> None:
            return None

    async def next_redraws(deadline: float) -> list[str]:
        loop = asyncio.get_running_loop()
        while loop.time() < deadline:
            drawn = redraws(master)
            if drawn:
                return drawn
            await asyncio.sleep(0.02)
        raise AssertionError("no redraw in time")

    async def scenario() -> None:
        hub = StatusHub(SNAPSHOT)
        path = tmp_path / "hostd.sock"
        server = asyncio.create_task(serve_control(path, hub, RecordingController({})))
        loop = asyncio.get_running_loop()
        await until(path.exists, timeout=10, what="the control socket")
        set_columns(master, 160)
        watcher = asyncio.create_task(demo.watch(path, Running()))
        try:
            for n, columns in enumerate((160, 100, 40, 12, 3, 70)):
                set_columns(master, columns)
                hub.update(job=dataclasses.replace(JOB, lines_acked=JOB.lines_acked + n))
                drawn = await next_redraws(loop.time() + 20)
                assert all(len(part) <= columns - 1 for part in drawn), (columns, drawn)
                if columns == 160:
                    assert "layer 42 of 309" in drawn[-1]
        finally:
            watcher.cancel()
            server.cancel()
            await asyncio.gather(watcher, server, return_exceptions=True)

    asyncio.run(scenario())
