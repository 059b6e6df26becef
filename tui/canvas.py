"""A braille canvas: polylines in mm drawn as 2x4 dots per terminal cell, a colour per cell."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from rich.style import Style
from rich.text import Text

# bit of each dot of a braille cell, indexed [row 0..3][column 0..1]
_BITS = np.array([[0x01, 0x08], [0x02, 0x10], [0x04, 0x20], [0x40, 0x80]], dtype=np.int64)


class Frame:
    """Maps millimetres (y up) to dots (y down) for a canvas of ``cols`` x ``rows`` cells.

    ``bounds`` (xmin, ymin, xmax, ymax) mm is fitted whole and centred, with the
    same scale on both axes (a braille dot is about square in a terminal).
    """

    def __init__(self, bounds: Sequence[float], cols: int, rows: int, margin: float = 1.0):
        xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        xmin, ymin, xmax, ymax = xmin - margin, ymin - margin, xmax + margin, ymax + margin
        self.cols, self.rows = max(1, cols), max(1, rows)
        width, height = self.cols * 2, self.rows * 4
        self.scale = min(width / max(xmax - xmin, 1e-6), height / max(ymax - ymin, 1e-6))
        self.x0 = xmin - (width / self.scale - (xmax - xmin)) / 2
        self.y1 = ymax + (height / self.scale - (ymax - ymin)) / 2

    def dots(self, points: np.ndarray) -> np.ndarray:
        """(k, 2) mm -> (k, 2) float dot positions (column, row)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        return np.column_stack(((points[:, 0] - self.x0) * self.scale,
                                (self.y1 - points[:, 1]) * self.scale))


class Canvas:
    """Dots on ``rows`` x ``cols`` braille cells, with a foreground and background per cell.

    Colours are palette indices (-1 = none); :meth:`text` turns them into styles.
    """

    def __init__(self, cols: int, rows: int) -> None:
        self.cols, self.rows = max(1, cols), max(1, rows)
        self.dots = np.zeros((self.rows * 4, self.cols * 2), dtype=bool)
        self.fg = np.full((self.rows, self.cols), -1, dtype=np.int64)
        self.bg = np.full((self.rows, self.cols), -1, dtype=np.int64)

    def polylines(self, lines: Sequence[np.ndarray], colour: int) -> None:
        """Draw polylines given in dot coordinates ((k, 2) arrays) in palette ``colour``."""
        starts, ends = [], []
        for line in lines:
            if len(line) >= 2:
                starts.append(line[:-1])
                ends.append(line[1:])
            elif len(line) == 1:
                starts.append(line)
                ends.append(line)
        if not starts:
            return
        a, b = np.concatenate(starts), np.concatenate(ends)
        steps = np.ceil(np.abs(b - a).max(axis=1)).astype(np.int64) + 1
        which = np.repeat(np.arange(len(a)), steps)
        first = np.cumsum(steps) - steps
        t = (np.arange(steps.sum()) - first[which]) / np.maximum(steps - 1, 1)[which]
        points = a[which] + (b - a)[which] * t[:, None]
        self.points(points, colour)

    def points(self, points: np.ndarray, colour: int) -> None:
        """Set the dots at (k, 2) dot positions (column, row) in palette ``colour``."""
        cols = np.floor(points[:, 0]).astype(np.int64)
        rows = np.floor(points[:, 1]).astype(np.int64)
        keep = (cols >= 0) & (cols < self.cols * 2) & (rows >= 0) & (rows < self.rows * 4)
        cols, rows = cols[keep], rows[keep]
        self.dots[rows, cols] = True
        self.fg[rows // 4, cols // 2] = colour

    def fill_background(self, values: np.ndarray, base: int) -> None:
        """Cell backgrounds from ``values`` (rows, cols) of palette offsets (< 0: none)."""
        self.bg = np.where(values >= 0, base + values, -1)

    def codes(self) -> np.ndarray:
        """(rows, cols) braille characters' code points."""
        cells = self.dots.reshape(self.rows, 4, self.cols, 2)
        return 0x2800 + np.einsum("rycx,yx->rc", cells.astype(np.int64), _BITS)

    def text(self, palette: Sequence[Style]) -> Text:
        """The canvas as Rich text, one line per row, runs of one style joined."""
        return Text("\n", no_wrap=True, overflow="crop").join(self.lines(palette))

    def lines(self, palette: Sequence[Style]) -> list[Text]:
        """Each row of the canvas as one Rich text, runs of one style joined.

        A cell without dots or background is a space (1 byte on the wire, where a
        blank braille character takes 3) in the colour of the run before it, so
        that runs of one colour broken by blanks need no new colour codes.
        """
        codes = self.codes()
        blank = (codes == 0x2800) & (self.bg < 0)
        fg = self.fg.copy()
        fg[blank] = -2  # takes the colour of the cell before it (or after, at a row's start)
        out = []
        for r in range(self.rows):
            row_fg = _fill_blanks(fg[r])
            line = "".join(" " if b else chr(c) for c, b in zip(codes[r], blank[r], strict=True))
            row = Text(no_wrap=True, overflow="crop")
            keys = row_fg * 10_000 + self.bg[r]
            breaks = np.flatnonzero(np.diff(keys)) + 1
            edges = [0, *breaks.tolist(), self.cols]
            for start, stop in itertools.pairwise(edges):
                fg_at, bg_at = int(row_fg[start]), int(self.bg[r, start])
                style = Style.combine([
                    palette[fg_at] if fg_at >= 0 else Style(),
                    Style(bgcolor=palette[bg_at].color) if bg_at >= 0 else Style(),
                ])
                row.append(line[start:stop], style)
            out.append(row)
        return out


def _fill_blanks(colours: np.ndarray) -> np.ndarray:
    """``colours`` with each -2 replaced by the nearest colour before it (after it for the
    leading ones; -1, no colour, for a row of blanks only)."""
    known = colours != -2
    if not known.any():
        return np.full_like(colours, -1)
    index = np.where(known, np.arange(len(colours)), 0)
    np.maximum.accumulate(index, out=index)
    filled = colours[index]
    first = int(np.argmax(known))
    filled[:first] = colours[first]
    return filled
