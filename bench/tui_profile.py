"""The dashboard under a profiler: which widgets refresh, and the terminal bytes each one costs.

``python -m bench.tui_profile --out FILE --socket PATH`` (or ``--mqtt HOST:PORT``)
runs what ``hostd tui`` runs with the same option (the single-printer dashboard,
or the fleet view), meant for a pseudo-terminal, with two counters:
``Widget.refresh`` calls by widget, and the bytes of every screen update
written to the terminal, cut at the widgets' edges and given to the widget
drawn there (its nearest ancestor with an id). Every second FILE is rewritten
with the totals so far as JSON: ``{"refreshes": {...}, "bytes": {...},
"updates": N, "full": N}``.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

from textual._compositor import ChopsUpdate, CompositorUpdate
from textual.app import App
from textual.widget import Widget

REFRESHES: Counter[str] = Counter()
BYTES: Counter[str] = Counter()
FRAMES: Counter[str] = Counter()


def label(widget: Any) -> str:
    """``#id`` of the widget or of its nearest ancestor with one, else its class name."""
    node = widget
    while node is not None:
        if getattr(node, "id", None):
            return f"#{node.id}"
        node = getattr(node, "parent", None)
    return type(widget).__name__


def _attribute(app: App[Any], update: ChopsUpdate) -> None:
    """Give the bytes of each piece of ``update`` (a line of one widget) to that widget."""
    console = app.console
    screen = app.screen
    for y, x1, x2 in update.spans:
        for end, (x, strip) in zip(update.chop_ends[y], update.chops[y].items(), strict=False):
            if strip is None or x > x2 or end <= x1:
                continue
            left, right = max(x, x1), min(end, x2)
            piece = ChopsUpdate(update.chops, [(y, left, right)], update.chop_ends)
            try:
                widget, _ = screen.get_widget_at(left, y)
            except Exception:  # no widget there (between frames)
                name = "?"
            else:
                name = label(widget)
            BYTES[name] += len(piece.render_segments(console).encode())


def install() -> None:
    """Wrap ``Widget.refresh`` and ``App._display`` with the counters."""
    refresh = Widget.refresh
    display = App._display

    def counted_refresh(self: Widget, *args: Any, **kwargs: Any) -> Any:
        REFRESHES[label(self)] += 1
        return refresh(self, *args, **kwargs)

    def counted_display(self: App[Any], screen: Any, renderable: Any) -> None:
        if isinstance(renderable, ChopsUpdate):
            FRAMES["updates"] += 1
            _attribute(self, renderable)
        elif isinstance(renderable, CompositorUpdate):
            FRAMES["full"] += 1
            BYTES["(full repaint)"] += len(renderable.render_segments(self.console).encode())
        display(self, screen, renderable)

    Widget.refresh = counted_refresh  # type: ignore[method-assign]
    App._display = counted_display  # type: ignore[method-assign]


def write(out: Path) -> None:
    """The totals so far, as JSON."""
    out.write_text(json.dumps({"t": time.monotonic(), "refreshes": dict(REFRESHES),
                               "bytes": dict(BYTES), **FRAMES}))


def main() -> int:
    """Run the profiled dashboard or fleet view until it is stopped."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--socket", help="the single-printer dashboard on this control socket")
    parser.add_argument("--mqtt", help="the fleet view on this broker, HOST:PORT")
    parser.add_argument("--redraw-s", type=float, default=0.0, help="as hostd tui's")
    args = parser.parse_args()
    install()
    app: App[Any]
    if args.mqtt:
        from tui.fleet import FleetApp
        from tui.sources import MqttSource, parse_brokers

        app = FleetApp(MqttSource(parse_brokers(args.mqtt)), redraw_s=args.redraw_s)
    else:
        from tui.app import Dashboard
        from tui.sources import SocketSource

        app = Dashboard(SocketSource(args.socket), redraw_s=args.redraw_s)

    def every_second() -> None:
        while True:
            time.sleep(1.0)
            write(args.out)

    threading.Thread(target=every_second, name="profile-writer", daemon=True).start()
    app.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
