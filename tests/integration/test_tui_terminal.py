"""What crosses the wire: partial screen updates leave the terminal as a full repaint would.

The dashboard sends only the cells that changed (``tui/widgets/lines.py``, the
fleet table's columns, ``tui/partial_output.py``). Here the real app runs on a
pseudo-terminal (``tests/terminal_story.py``), its output is fed to a terminal
emulator (pyte), and the screen built from partial updates only is compared,
cell by cell (character, colours, bold, reverse), with the same screen after a
full repaint.
"""

from __future__ import annotations

import fcntl
import os
import select
import struct
import subprocess
import sys
import termios
import time

import pyte
import pytest
from support.paths import ROOT

PARTIAL, FULL = b"\x1b]0;story-partial\x07", b"\x1b]0;story-full\x07"
COLOURS = {"truecolor": {"TERM": "xterm-256color", "COLORTERM": "truecolor"},
           "256": {"TERM": "xterm-256color"}}


def run_story(story: str, columns: int, rows: int, colours: str) -> bytes:
    """Everything the story's app writes to a ``columns`` x ``rows`` terminal."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    env = {k: v for k, v in os.environ.items()
           if k not in ("TERM", "COLORTERM", "NO_COLOR", "TEXTUAL_COLOR_SYSTEM")}
    env.update(COLOURS[colours], PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests/support/terminal_story.py"), story],
                            stdin=slave, stdout=slave, stderr=slave, env=env, cwd=ROOT,
                            start_new_session=True)
    os.close(slave)
    out = b""
    deadline = time.monotonic() + 90
    try:
        while FULL not in out:
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f"the story did not finish; last output {out[-600:]!r}")
            ready, _, _ = select.select([master], [], [], left)
            if ready:
                try:
                    data = os.read(master, 65536)
                except OSError:
                    data = b""
                if not data:
                    raise AssertionError(f"the story ended early: {out[-1500:]!r}")
                out += data
        proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    return out


def cells(screen: pyte.Screen) -> list[list[tuple]]:
    """Every cell of the emulated screen: character, colours, bold, reverse."""
    return [[(c.data, c.fg, c.bg, c.bold, c.reverse) for c in
             (screen.buffer[y][x] for x in range(screen.columns))] for y in range(screen.lines)]


@pytest.mark.parametrize(("story", "size", "colours"), [
    ("printer", (80, 24), "truecolor"), ("printer", (200, 60), "256"),
    ("fleet", (80, 24), "256"), ("fleet", (200, 60), "truecolor"),
])
def test_partial_updates_leave_what_a_full_repaint_shows(
        story: str, size: tuple[int, int], colours: str) -> None:
    columns, rows = size
    out = run_story(story, columns, rows, colours)
    partial, _, full = out.partition(PARTIAL)
    full = full.partition(FULL)[0]
    screen = pyte.Screen(columns, rows)
    stream = pyte.ByteStream(screen)
    stream.feed(partial)
    built = cells(screen)
    stream.feed(full)
    repainted = cells(screen)
    shown = "\n".join("".join(cell[0] for cell in row) for row in repainted)
    assert ("idle" if story == "printer" else "farm-02") in shown.lower()
    wrong = [(y, x, built[y][x], repainted[y][x]) for y in range(rows) for x in range(columns)
             if built[y][x] != repainted[y][x]]
    assert not wrong, f"{len(wrong)} cells differ, first {wrong[:5]}\n{shown}"
    # the partial phase did send partial updates: far less than a repaint per status
    assert len(partial) < 40 * len(full)
