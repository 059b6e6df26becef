"""The current layer drawn with braille dots: toolpaths by type, printed part brighter, field."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from rich.style import Style
from rich.text import Text
from textual.timer import Timer

from tui.canvas import Canvas, Frame
from tui.format import layer_text
from tui.widgets.lines import LinesWidget

# (printed, still to come) colour of each ;TYPE: kind. Chosen so that every colour stays
# its own in 256 and in 16 colours too (rich's downgrade, as Textual's output does it):
# printed near the bright ANSI colours (9-15), to come near the normal ones (1-8).
KINDS = {
    "WALL-OUTER": ("#ff5f5f", "#9a2828"),  # red: 9 / 1 in 16 colours
    "WALL-INNER": ("#5fd7d7", "#208080"),  # cyan: 14 / 6
    "SKIN": ("#f0e050", "#8a6a1a"),  # yellow: 11 / 3
    "FILL": ("#5fd75f", "#2a802a"),  # green: 10 / 2
    "SUPPORT": ("#7090ff", "#2838a0"),  # blue: 12 / 4
}
OTHER = ("#d0d0d0", "#555555")  # grey: 7 / 8
LEGEND = (("WALL-OUTER", "outer"), ("WALL-INNER", "inner"), ("SKIN", "skin"),
          ("FILL", "infill"), ("SUPPORT", "support"))
PRINTED_NOTE = "bright printed · dim to come"  # the picture's bottom border
HIGHLIGHT = "#ffffff"  # 15
CANCELLED = "#ff00ff"  # magenta: 13
FIELD_LEVELS = 16
PROGRESS_S = 1.0  # the progress within a layer is drawn at most once a second


def _field_palette() -> list[Style]:
    """Dark blue to yellow (the PNG preview's colour map), FIELD_LEVELS steps."""
    anchors = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98],
                        [253, 231, 37]], dtype=float)
    out = []
    for t in np.linspace(0.0, 1.0, FIELD_LEVELS):
        at = t * (len(anchors) - 1)
        low = min(int(at), len(anchors) - 2)
        r, g, b = anchors[low] * (1 - (at - low)) + anchors[low + 1] * (at - low)
        out.append(Style(color=f"#{int(r):02x}{int(g):02x}{int(b):02x}"))
    return out


class LayerView(LinesWidget):
    """Draws the ``layer`` reply of the control API, sized to the widget.

    ``printed`` is the number of the layer's commands acknowledged (None: the
    whole layer is still to come). A new layer, the field or a highlighted body
    is drawn at once (with ``layer_s``, for a slow link, a new layer at most once
    every ``layer_s`` seconds); the acknowledged progress within a layer at most
    once every ``progress_s`` seconds of ``clock`` (the last value always shown,
    a timer draws it when its turn comes), and only when a path turns bright.
    Either way only the picture's rows that changed are sent to the terminal.
    """

    def __init__(self, *, progress_s: float = PROGRESS_S, layer_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.data: dict[str, Any] | None = None
        self.printed: int | None = None
        self.message = "waiting for a job"
        self.show_field = False
        self.highlight: int | None = None
        self.progress_s = progress_s
        self.layer_s = layer_s  # > 0: a new layer too at most once every layer_s seconds
        self.clock = clock
        self.drawn: dict[str, Any] | None = None  # the layer in the picture as last drawn
        self.drawn_paths = 0  # printed paths in the picture as last drawn
        self._drawn_message = self.message
        self._drawn_at = -math.inf  # clock() of the last progress drawn
        self._timer: Timer | None = None  # draws progress held back by progress_s
        self._cache: tuple[tuple, list[Text]] | None = None
        pairs = (*KINDS.values(), OTHER)
        self._palette = [Style(color=colour) for pair in pairs for colour in pair]
        self._palette += [Style(color=HIGHLIGHT), Style(color=CANCELLED), *_field_palette()]

    def show(self, data: dict[str, Any] | None, message: str = "") -> None:
        """A new layer (or none, with a message saying why), all of it to come: drawn at
        once, and so is the :meth:`progress` that follows; with ``layer_s`` (a slow
        link) at most once every ``layer_s`` seconds."""
        self.data, self.message, self.printed = data, message, None
        if self.layer_s <= 0:
            self._draw()
            self._drawn_at = -math.inf
        elif self.data is not self.drawn or self.message != self._drawn_message:
            self._due(self.layer_s)

    def progress(self, printed: int | None) -> None:
        """How many of the layer's commands are acknowledged; drawn when a path turns
        bright, at most once every ``progress_s`` seconds."""
        self.printed = printed
        if self.printed_paths() == self.drawn_paths:
            return  # nothing visible changed
        self._due(self.progress_s)

    def redraw_now(self) -> None:
        """Draw what is set now (after the field or the highlight changed)."""
        self._draw()

    def _due(self, interval: float) -> None:
        """Draw now if the last drawing is ``interval`` s old, else when it will be."""
        if self._timer is not None:
            return  # a drawing is already due; it draws what is set then
        wait = self._drawn_at + interval - self.clock()
        if wait <= 0:
            self._draw()
        else:
            self._timer = self.set_timer(wait, self._draw)

    def _draw(self) -> None:
        if self._timer is not None:
            self._timer.stop()
            self._timer = None
        paths = self.printed_paths()
        changed = (paths != self.drawn_paths or self.data is not self.drawn
                   or self.message != self._drawn_message)
        if changed:
            self._drawn_at = self.clock()
        self.drawn_paths, self.drawn, self._drawn_message = paths, self.data, self.message
        self.set_border_title(self.title(self.data))
        subtitle = PRINTED_NOTE if self.data is not None else ""
        if self.border_subtitle != subtitle:
            self.border_subtitle = subtitle
        self.redraw()

    def printed_paths(self) -> int:
        """How many of the layer's paths are wholly printed."""
        if self.data is None or self.printed is None:
            return 0
        ends = [path["end"] for path in self.data["paths"]]
        return int(np.searchsorted(ends, self.printed, side="right"))

    def picture(self) -> str:
        """The picture as drawn now, without its legend: braille dots, one line per row."""
        size = self.content_size
        return "\n".join(line.plain for line in self.content_lines(size.width, size.height)[:-1])

    def content_lines(self, width: int, height: int) -> list[Text]:
        if self.drawn is None or height < 2:
            return [Text(self._drawn_message, style="dim", no_wrap=True, overflow="ellipsis")]
        data = self.drawn
        done = self.drawn_paths
        key = (width, height, id(data), done, self.show_field, self.highlight)
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        rows = height - 1
        frame = Frame(data["bounds"], width, rows)
        canvas = Canvas(width, rows)
        if self.show_field and data.get("field"):
            canvas.fill_background(self._field_cells(data["field"], frame, canvas),
                                   base=len(self._palette) - FIELD_LEVELS)
        kinds = list(KINDS)
        for stage, paths in ((1, data["paths"][done:]), (0, data["paths"][:done])):
            by_kind: dict[int, list[np.ndarray]] = {}
            for path in paths:
                slot = kinds.index(path["kind"]) if path["kind"] in KINDS else len(kinds)
                by_kind.setdefault(slot * 2 + stage, []).append(frame.dots(path["points"]))
            for colour, lines in by_kind.items():
                canvas.polylines(lines, colour)
        highlight = len(KINDS) * 2 + 2
        for body in data.get("bodies") or ():
            if body["index"] == self.highlight or body["cancelled"]:
                rings = [frame.dots(ring) for ring in body["rings"]]
                canvas.polylines(rings, highlight + (1 if body["cancelled"] else 0))
        drawn = [*canvas.lines(self._palette), self._legend(width)]
        self._cache = (key, drawn)
        return drawn

    def _field_cells(self, field: dict[str, Any], frame: Frame, canvas: Canvas) -> np.ndarray:
        """Field levels (0..FIELD_LEVELS-1, -1 outside) at the centre of every cell."""
        values = np.asarray(field["values"], dtype=np.int64)
        xmin, ymin, xmax, ymax = (self.drawn or {})["bounds"]
        cx = frame.x0 + (np.arange(canvas.cols) * 2 + 1) / frame.scale
        cy = frame.y1 - (np.arange(canvas.rows) * 4 + 2) / frame.scale
        col = np.floor((cx - xmin) / max(xmax - xmin, 1e-6) * field["columns"]).astype(int)
        row = np.floor((ymax - cy) / max(ymax - ymin, 1e-6) * field["rows"]).astype(int)
        ok_c = (col >= 0) & (col < field["columns"])
        ok_r = (row >= 0) & (row < field["rows"])
        out = np.full((canvas.rows, canvas.cols), -1, dtype=np.int64)
        grid = values[np.clip(row, 0, field["rows"] - 1)][:, np.clip(col, 0, field["columns"] - 1)]
        inside = ok_r[:, None] & ok_c[None, :] & (grid >= 0)
        out[inside] = grid[inside] * FIELD_LEVELS // 256
        return out

    def _legend(self, width: int) -> Text:
        data = self.drawn or {}
        text = Text(no_wrap=True, overflow="ellipsis", end="")
        if self.show_field and data.get("field"):
            field = data["field"]
            text.append(f"field {field['name']} ", "bold")
            for style in self._palette[-FIELD_LEVELS::3]:
                text.append("█", style)
            text.append(f" {field['low']:g}..{field['high']:g}", "dim")
            return text
        for kind, name in LEGEND:  # whole entries only, as many as fit
            gap = " " if text.plain else ""
            if text.cell_len + len(gap) + 1 + len(name) > width:
                break
            text.append(gap)
            text.append("■", KINDS[kind][0])
            text.append(name)
        return text

    @staticmethod
    def title(data: dict[str, Any] | None) -> str:
        """The border title: layer N of M and its height."""
        if data is None:
            return "layer"
        return f"{layer_text(data['layer'], data['layers'])} · z {data['z']:.2f} mm"
