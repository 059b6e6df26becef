"""What the dashboard writes to its terminal: bytes per second, as they would cross an SSH link.

``python -m bench.terminal_bytes`` runs the real ``hostd tui`` in a pseudo-terminal
(its size set with ``TIOCSWINSZ``) and counts every byte it writes in a fixed
window after a warm-up, for each view, size and colour system:

- ``printer``: the single-printer dashboard (``hostd tui --socket``) on a real
  ``hostd run`` daemon printing the dogbone on the simulated printer at the
  demo's speed (``make run``: 50 times real time, heating included), so a
  layer starts about every second, with its event; ``--time-scale 0.2`` runs
  it at 5x instead (a layer every ten seconds or so: nearer a real printer,
  whose layers take a minute);
- ``fleetN``: the fleet view (``hostd tui --mqtt``) on a mosquitto where the
  light publisher (``bench/fleetpub.py``) emulates N printers at one status a
  second each.

Sizes 80x24 and 200x60; ``TERM=xterm-256color`` alone (256 colours) and with
``COLORTERM=truecolor``. Each run reports the mean bytes per second over the
window and the worst second, against the 8,000 B/s of a 64 kbit/s link and the
32,000 B/s of a 256 kbit/s one. ``--profile`` runs the same views under
``bench/tui_profile.py`` and prints, per widget, the refreshes and bytes a second.
Loopback only; every wait is bounded.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import sys
import tempfile
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from bench.daemonproc import Daemon, DaemonSetup
from bench.fleet import PYTHON_ENV, ROOT, start_publisher, stop_process
from bench.fleet_term import COLOUR_256, TRUECOLOUR, Terminal
from bench.slice_vs_peers import hostd_executable
from hostd.api import ControlClient, ControlError

sys.path.insert(0, str(ROOT / "tests"))
from support.brokers import HOST, start_broker

SIZES = {"80x24": (80, 24), "200x60": (200, 60)}
COLOURS = {"256": COLOUR_256, "truecolor": TRUECOLOUR}
LINKS = (("64 kbit/s", 8_000), ("256 kbit/s", 32_000))
MODEL = "dogbone_100x30x5.stl"  # the demo's part (hostd/data)
COPIES = 4  # dropped at once, so a job is printing for the whole scenario
DEMO_TIME_SCALE = 0.02  # hostd/data/demo.toml: 50 times real time


@dataclass(frozen=True)
class DemoSetup(DaemonSetup):
    """The demo's daemon (``hostd/data/demo.toml``: the embedded default at 50x) in a folder;
    ``time_scale`` > 0 replaces the demo's."""

    def toml(self, jobs: Path, state: Path) -> str:
        demo = (resources.files("hostd.data") / "demo.toml").read_text()
        if self.time_scale > 0:
            demo = re.sub(r"(?m)^time_scale = .*$", f"time_scale = {self.time_scale}", demo)
        return (f'[jobs]\nfolder = "{jobs}"\nsettle_s = {self.settle_s}\n\n'
                f'[state]\nfolder = "{state}"\n\n{demo}')


@dataclass
class Run:
    """What one dashboard wrote in one window."""

    view: str
    size: str
    colours: str
    seconds: list[int]  # bytes written in each second of the window
    startup: int  # bytes written before the window (first paint and warm-up)
    profile: dict[str, dict[str, float]] | None = None

    @property
    def mean(self) -> float:
        """Mean bytes per second over the window."""
        return sum(self.seconds) / max(1, len(self.seconds))

    @property
    def worst(self) -> int:
        """Bytes of the worst second."""
        return max(self.seconds, default=0)

    def row(self) -> str:
        """One Markdown row: mean and worst second, and their share of each slow link."""
        links = " | ".join(f"{100 * self.mean / rate:.0f} % / {100 * self.worst / rate:.0f} %"
                           for _, rate in LINKS)
        return (f"| {self.view} | {self.size} | {self.colours} | {self.mean:,.0f} | "
                f"{self.worst:,} | {links} | {self.startup:,} |")


HEADER = ("| view | terminal | colours | mean B/s | worst 1 s (B) | "
          + " | ".join(f"of {name} (mean / worst)" for name, _ in LINKS)
          + " | bytes before the window |\n|---|---|---|---|---|---|---|---|")


def measure(command: list[str], view: str, size: str, colours: str, warmup: float,
            window: float, profile: Path | None = None) -> Run:
    """Run ``command`` on a terminal of ``size`` and count its bytes in each second."""
    columns, rows = SIZES[size]
    term = Terminal(command, cwd=ROOT, env=PYTHON_ENV, columns=columns, rows=rows,
                    term=COLOURS[colours])
    try:
        deadline = time.monotonic() + 30.0
        while term.bytes_out == 0 and time.monotonic() < deadline:  # the first paint
            time.sleep(0.05)
        time.sleep(warmup)
        before = _profile(profile)
        start = time.monotonic()
        time.sleep(window)
        after = _profile(profile)
        if term.proc.poll() is not None:
            raise RuntimeError(f"{command[0]} exited: {term.tail[-400:]!r}")
        seconds = [term.bytes_between(start + i, start + i + 1) for i in range(int(window))]
        run = Run(view, size, colours, seconds, term.bytes_between(0.0, start))
        if before and after:
            run.profile = _rates(before, after)
        return run
    finally:
        term.close()


def _profile(path: Path | None) -> dict | None:
    if path is None:
        return None
    time.sleep(1.1)  # the profiler rewrites its totals every second
    return json.loads(path.read_text()) if path.exists() else None


def _rates(before: dict, after: dict) -> dict[str, dict[str, float]]:
    """Refreshes and bytes a second of each widget between two profiler totals."""
    span = max(1e-6, after["t"] - before["t"])
    out: dict[str, dict[str, float]] = {}
    for kind in ("refreshes", "bytes"):
        for name, total in after[kind].items():
            rate = (total - before[kind].get(name, 0)) / span
            out.setdefault(name, {"refreshes": 0.0, "bytes": 0.0})[kind] = rate
    out["(screen updates)"] = {"refreshes": (after.get("updates", 0)
                                             - before.get("updates", 0)) / span,
                               "bytes": 0.0}
    return out


def command(args: argparse.Namespace, target: list[str], out: Path) -> list[str]:
    """``hostd tui TARGET``, or the profiled dashboard writing its totals to ``out``."""
    if args.redraw_s:
        target = [*target, "--redraw-s", f"{args.redraw_s:g}"]
    if args.profile:
        return [sys.executable, "-m", "bench.tui_profile", "--out", str(out), *target]
    return [*hostd_executable(), "tui", *target]


async def _printing(socket: Path, timeout: float) -> None:
    """Wait until the daemon prints a sliced layer."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            async with ControlClient(str(socket)) as client:
                snap = await client.status()
            if snap.state == "printing" and snap.job is not None and snap.job.layers:
                return
        except (ControlError, OSError):
            pass
        await asyncio.sleep(0.2)
    raise RuntimeError(f"the daemon did not start printing in {timeout:.0f} s")


def printer_runs(args: argparse.Namespace, tmp: Path) -> list[Run]:
    """The single-printer dashboard on the demo daemon, every size and colour system."""
    runs = []
    view = f"printer, {1 / args.time_scale:g}x"
    with Daemon(DemoSetup(time_scale=args.time_scale)) as daemon:
        daemon.wait_ready()
        socket = next(p for p in daemon.state.rglob("*") if p.is_socket())
        with resources.as_file(resources.files("hostd.data") / MODEL) as model:
            for n in range(COPIES):
                copy = tmp / f"dogbone{n}.stl"
                copy.write_bytes(model.read_bytes())
                daemon.drop(copy)
        for size, colours in plan(args):
            asyncio.run(_printing(socket, 180.0))
            print(f"printer {size} {colours} ...", file=sys.stderr, flush=True)
            runs.append(measure(command(args, ["--socket", str(socket)], tmp / "profile.json"),
                                view, size, colours, args.warmup, args.window,
                                tmp / "profile.json" if args.profile else None))
            print(runs[-1].row(), file=sys.stderr, flush=True)
    return runs


def fleet_runs(args: argparse.Namespace, tmp: Path, count: int) -> list[Run]:
    """The fleet view of ``count`` emulated printers, every size and colour system."""
    runs = []
    broker = start_broker(tmp / "mosquitto")
    combos = plan(args)
    publisher = start_publisher(f"{HOST}:{broker.port}", count,
                                len(combos) * (args.warmup + args.window + 15) + 30)
    try:
        for size, colours in combos:
            print(f"fleet{count} {size} {colours} ...", file=sys.stderr, flush=True)
            runs.append(measure(command(args, ["--mqtt", f"{HOST}:{broker.port}"],
                                        tmp / "profile.json"),
                                f"fleet, {count:,} printers", size, colours, args.warmup,
                                args.window, tmp / "profile.json" if args.profile else None))
            print(runs[-1].row(), file=sys.stderr, flush=True)
    finally:
        stop_process(publisher)
        broker.stop()
    return runs


def plan(args: argparse.Namespace) -> list[tuple[str, str]]:
    """Every (size, colour system) asked for."""
    return [(size, colours) for size in args.sizes.split(",")
            for colours in args.colours.split(",")]


def print_profile(runs: list[Run]) -> None:
    """Per run, each widget's refreshes and bytes a second, most bytes first."""
    for run in runs:
        if not run.profile:
            continue
        print(f"\n{run.view} {run.size} {run.colours}: {run.mean:,.0f} B/s")
        print("| widget | refreshes/s | bytes/s |\n|---|---|---|")
        for name, rates in sorted(run.profile.items(), key=lambda kv: -kv[1]["bytes"]):
            print(f"| {name} | {rates['refreshes']:.1f} | {rates['bytes']:,.0f} |")


def main() -> int:
    """Run the chosen views and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", default="printer,fleet100,fleet1000")
    parser.add_argument("--sizes", default=",".join(SIZES))
    parser.add_argument("--colours", default=",".join(COLOURS))
    parser.add_argument("--warmup", type=float, default=4.0, help="seconds after the first paint")
    parser.add_argument("--window", type=float, default=20.0, help="measured seconds")
    parser.add_argument("--time-scale", type=float, default=DEMO_TIME_SCALE,
                        help="printer: simulated printer's time scale (0.02: the demo's 50x)")
    parser.add_argument("--redraw-s", type=float, default=0.0,
                        help="run hostd tui --redraw-s S (the slow-link setting)")
    parser.add_argument("--profile", action="store_true",
                        help="count refreshes and bytes per widget (bench/tui_profile.py)")
    args = parser.parse_args()
    runs: list[Run] = []
    for view in args.views.split(","):
        with tempfile.TemporaryDirectory(prefix="hostd-termbytes-") as folder:
            if view == "printer":
                runs += printer_runs(args, Path(folder))
            elif view.startswith("fleet"):
                runs += fleet_runs(args, Path(folder), int(view.removeprefix("fleet")))
            else:
                parser.error(f"unknown view {view!r}")
    if args.redraw_s:
        print(f"hostd tui --redraw-s {args.redraw_s:g}\n")
    print(HEADER)
    print("\n".join(run.row() for run in runs))
    if args.profile:
        print_profile(runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
