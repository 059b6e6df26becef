"""Screen updates that start where the change starts, not at the widget's left edge.

Textual writes a refreshed region of a widget from the widget's left edge to
the region's right end (``ChopsUpdate.render_segments`` crops only the right
side). The dashboard refreshes only the cells that changed (a number in a
panel, a column of the fleet table, the paths of the layer picture that turned
bright), so that would send most of each row again. :func:`install` replaces
that method with one that crops both sides: each region is written from its own
first cell. Where Textual's update class is not the expected one it is left
alone (updates stay correct, only larger).
"""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.control import Control

try:
    from textual._compositor import ChopsUpdate
except ImportError:  # another Textual layout: nothing to patch
    ChopsUpdate = None  # type: ignore[assignment,misc]

_FIELDS = ("chops", "spans", "chop_ends")


def render_segments(self: Any, console: Console) -> str:
    """The update as terminal data: for each line span, only the cells inside it."""
    sequences: list[str] = []
    append = sequences.append
    move_to = Control.move_to
    last_y = self.spans[-1][0]
    for y, x1, x2 in self.spans:
        line = self.chops[y]
        for end, (x, strip) in zip(self.chop_ends[y], line.items(), strict=False):
            if strip is None or x > x2 or end <= x1:
                continue
            start, stop = max(x, x1), min(end, x2)
            if stop <= start:
                continue
            piece = strip if (start, stop) == (x, end) else strip.crop(start - x, stop - x)
            append(move_to(start, y).segment.text)
            append(piece.render(console))
        if y != last_y:
            append("\n")
    return "".join(sequences)


def install() -> bool:
    """Make Textual's partial updates start at each region's first cell; True if done."""
    if ChopsUpdate is None or not hasattr(ChopsUpdate, "render_segments"):
        return False
    if ChopsUpdate.render_segments is render_segments:
        return True
    init = getattr(ChopsUpdate.__init__, "__code__", None)
    if init is None or not all(name in init.co_varnames for name in _FIELDS):
        return False
    ChopsUpdate.render_segments = render_segments
    return True
