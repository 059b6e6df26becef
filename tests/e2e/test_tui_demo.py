"""`make run` on a terminal: the dashboard opens on the demo daemon; q ends the demo cleanly."""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

from support.daemon_helpers import daemon_pids
from support.paths import ROOT


def _read_until(fd: int, needles: tuple[bytes, ...], timeout: float) -> bytes:
    seen = b""
    deadline = time.monotonic() + timeout
    while not all(needle in seen for needle in needles):
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"{needles} not shown; got {seen[-2000:]!r}")
        ready, _, _ = select.select([fd], [], [], left)
        if ready:
            try:
                seen += os.read(fd, 65536)
            except OSError:  # the terminal closed
                break
    return seen


def test_demo_opens_the_dashboard_and_q_stops_everything(tmp_path: Path) -> None:
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))
    env = {**os.environ, "TERM": "xterm-256color", "PYTHONPATH": str(ROOT), "COLUMNS": "80",
           "LINES": "24"}
    demo = subprocess.Popen([sys.executable, "-m", "hostd.app.demo"], cwd=tmp_path, stdin=slave,
                            stdout=slave, stderr=slave, env=env, start_new_session=True)
    os.close(slave)
    try:
        shown = _read_until(master, (b"dogbone.stl", b"PRINTING", b"Quit"), 90)
        assert b"layer " in shown
        os.write(master, b"q")
        rest = b""
        deadline = time.monotonic() + 40
        while demo.poll() is None and time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    rest += os.read(master, 65536)
                except OSError:
                    break
        assert demo.wait(timeout=10) == 0
        assert b"daemon exited with code 0" in rest
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
        os.close(master)
    assert daemon_pids(tmp_path) == []
    executed = (tmp_path / "var" / "simulator-executed.log").read_text().splitlines()
    assert any(line.startswith("G1") and " E" in line for line in executed)


def test_hostd_print_progress_line_fits_the_terminal(monkeypatch) -> None:
    import io

    from hostd.app.commands.print_file import Progress, ProgressBar, fit_bar

    for columns in (2, 5, 12, 19, 20, 32, 50, 80, 200):
        out = io.StringIO()
        monkeypatch.setenv("COLUMNS", str(columns))  # not a terminal: $COLUMNS says the width
        bar = ProgressBar(out)
        progress = Progress("layers", 309, done=101, acked=99_500, hotend=(209.7, 210.0),
                            layer_ends=[1000 * (k + 1) for k in range(101)])
        bar.draw(progress, final=True)
        line = out.getvalue().strip("\r\n")
        assert 0 < len(line) < columns, (columns, line)
        if columns >= 80:
            assert "layer 100 of 309" in line  # 99 layers wholly acknowledged: the 100th prints
            assert line.startswith("[")
    assert fit_bar(0.5, "tail", 12) == "tail"  # no room for a bar: the text alone
