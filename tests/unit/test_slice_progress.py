"""`hostd slice`'s progress line: the one bar on the one live line, never wider than the
terminal."""

from __future__ import annotations

import io

import pytest

from hostd.api import bar
from hostd.app.commands.slice import ProgressBar


def _lines(columns: int, total: int = 40) -> list[str]:
    stream = io.StringIO()
    progress = ProgressBar(stream, "slicing", columns=columns)
    for done in range(total + 1):
        progress._last = 0.0  # every call redraws (no clock between them)
        progress(done, total)
    text = stream.getvalue()
    assert text.endswith("\n")
    return text[:-1].split("\r")[1:]


def test_a_wide_terminal_shows_label_bar_and_layers() -> None:
    last = _lines(80)[-1]
    assert last.startswith(f"slicing [{bar(1.0, 30, ascii=True)}] 100.0% layer 40/40 ")
    assert last.endswith("s")


@pytest.mark.parametrize("columns", [20, 45, 60])
def test_no_redraw_is_wider_than_a_narrow_terminal(columns: int) -> None:
    lines = _lines(columns)
    assert all(len(line) <= columns - 1 for line in lines)
    assert lines[-1].startswith("slicing ")
