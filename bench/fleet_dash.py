"""The fleet view under measurement: records the publish-to-screen lag of every status shown.

``python -m bench.fleet_dash --broker HOST:PORT[,...] --lags FILE`` runs the real
fleet view (meant to run in a pseudo-terminal) and appends, about once a second,
one line per shown status to FILE: the seconds from the status' timestamp (the
publisher stamps it just before publishing) to the screen update that showed it.
``--svg FILE`` instead saves one screenshot (Textual's SVG export) after
``--wait`` seconds, without a terminal.
"""

from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path
from typing import Any

from tui.fleet import FleetApp, FleetScreen
from tui.sources import MqttSource, parse_brokers


class MeasuredScreen(FleetScreen):
    """The fleet screen, timing each status it shows."""

    def __init__(self, source: Any, lags: Path) -> None:
        super().__init__(source)
        self.collect_stamps = True
        self.lags_path = lags
        self.pending: list[float] = []

    def on_mount(self) -> None:  # runs after FleetScreen.on_mount (Textual calls both)
        self.set_interval(1.0, self.write_lags)

    def rows_shown(self, stamps: list[float]) -> None:
        now = time.time()
        self.pending.extend(now - stamp for stamp in stamps)

    def write_lags(self) -> None:
        if self.pending:
            with self.lags_path.open("a") as handle:
                handle.write("".join(f"{lag:.4f}\n" for lag in self.pending))
            self.pending.clear()


class MeasuredApp(FleetApp):
    """The fleet app with the measured screen."""

    def __init__(self, source: Any, lags: Path) -> None:
        super().__init__(source)
        self.lags = lags

    def fleet_screen(self) -> FleetScreen:
        return MeasuredScreen(self.source, self.lags)


async def screenshot(source: MqttSource, out: Path, size: tuple[int, int], wait: float) -> None:
    """Run the fleet view headless for ``wait`` s, then save its SVG to ``out``."""
    app = FleetApp(source, refresh_s=0.1)
    async with app.run_test(size=size) as pilot:
        await asyncio.sleep(wait)
        await pilot.pause()
        out.write_text(app.export_screenshot(title="hostd tui --mqtt"))


def main() -> int:
    """Run the measured fleet view, or take a screenshot."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--broker", required=True, metavar="HOST:PORT[,HOST:PORT...]")
    parser.add_argument("--lags", type=Path, help="append lags (s) to this file")
    parser.add_argument("--svg", type=Path, help="save a screenshot here and exit")
    parser.add_argument("--size", default="110x32", help="screenshot size, COLUMNSxROWS")
    parser.add_argument("--wait", type=float, default=3.0)
    args = parser.parse_args()
    source = MqttSource(parse_brokers(args.broker))
    if args.svg:
        cols, rows = (int(v) for v in args.size.split("x"))
        asyncio.run(screenshot(source, args.svg, (cols, rows), args.wait))
        return 0
    if args.lags is None:
        parser.error("--lags or --svg is needed")
    MeasuredApp(source, args.lags).run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
