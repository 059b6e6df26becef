"""`hostd print FILE --port PORT`: stream G-code (or an STL sliced just in time) to a printer."""

from __future__ import annotations

import argparse
import asyncio
import bisect
import concurrent.futures
import contextlib
import signal
import sys
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

from drivers.link.protocol import Response, strip_comment
from drivers.link.streamer import AckChannel, LinkError, StreamCancelled, Streamer, StreamerConfig
from drivers.link.transport import TransportError, open_transport
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig
from hostd.api import layer_in_progress
from hostd.app.cli import EXIT_FAILURE, EXIT_OK, UsageError
from hostd.app.liveline import LiveLine, fit_bar
from hostd.printing.endgcode import CANCEL_GCODE
from slicer.pipeline import LayerWindow

GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")
LAYERS_AHEAD = 3


@dataclass
class Progress:
    """How far the job is: ``done`` of ``total`` units (lines or layers) handed to the
    streamer, ``acked`` lines the printer acknowledged; for layers, ``layer_ends`` is the
    count of commands sent through the end of each layer handed over."""

    unit: str
    total: int
    done: int = 0
    acked: int = 0
    hotend: tuple[float, float | None] | None = None
    layer_ends: list[int] = field(default_factory=list)

    def completed_layers(self) -> int:
        """Layers whose every command the printer acknowledged."""
        return bisect.bisect_right(self.layer_ends, self.acked)

    def layer(self) -> int:
        """The 0-based layer being printed, from the acknowledged lines (as the daemon says)."""
        return layer_in_progress(self.completed_layers() - 1, self.total)


class ProgressBar:
    """One text line on ``stream``, redrawn at most ten times a second, never wider than
    the terminal (``columns``, else the stream's terminal's width read at each redraw)."""

    def __init__(self, stream: TextIO, width: int = 30, enabled: bool = True,
                 columns: int | None = None) -> None:
        self.stream = stream
        self.width = width
        self.line = LiveLine(stream, columns)
        self.enabled = enabled
        self.started = time.monotonic()
        self._last = 0.0

    def draw(self, progress: Progress, final: bool = False) -> None:
        """Redraw the bar (always when ``final``)."""
        now = time.monotonic()
        if not self.enabled or (not final and now - self._last < 0.1):
            return
        self._last = now
        if progress.unit == "layers":
            done = progress.completed_layers()
            count = f"layer {progress.layer() + 1} of {progress.total}"
        else:
            done = progress.done
            count = f"{progress.done}/{progress.total} {progress.unit}"
        frac = min(1.0, done / progress.total) if progress.total else 1.0
        temp = ""
        if progress.hotend is not None:
            actual, target = progress.hotend
            temp = f" T {actual:.0f}/{target:.0f}" if target is not None else f" T {actual:.0f}"
        tail = f"{100 * frac:5.1f}% {count} {progress.acked} acked{temp} {now - self.started:.1f}s"
        self.line.draw(fit_bar(frac, tail, self.line.width() + 1, self.width))
        if final:
            self.line.end()


def gcode_commands(path: Path) -> tuple[int, Callable[[Progress], AsyncIterator[str]]]:
    """Count the file's commands, and a generator of them that advances ``progress``."""
    with path.open(encoding="utf-8", errors="replace") as handle:
        total = sum(1 for line in handle if strip_comment(line))

    async def commands(progress: Progress) -> AsyncIterator[str]:
        with path.open(encoding="utf-8", errors="replace") as handle:
            for line in handle:
                command = strip_comment(line)
                if command:
                    yield command
                    progress.done += 1

    return total, commands


def stl_commands(plan) -> Callable[[Progress], AsyncIterator[str]]:
    """Start G-code, every layer sliced a few layers ahead on worker threads, end G-code.

    The window ahead is :class:`slicer.pipeline.LayerWindow`, as in the daemon.
    """

    async def commands(progress: Progress) -> AsyncIterator[str]:
        start = [c for c in map(strip_comment, plan.start_gcode()) if c]
        sent = len(start)
        for command in start:
            yield command
        with concurrent.futures.ThreadPoolExecutor(thread_name_prefix="print-slice") as pool:
            window: LayerWindow[list[str]] = LayerWindow(
                lambda index: pool.submit(plan.layer_gcode, index), plan.layer_count,
                LAYERS_AHEAD + 1,
            )
            try:
                for i in range(plan.layer_count):
                    layer = [c for c in map(strip_comment, await window.take_async(i)) if c]
                    sent += len(layer)
                    progress.layer_ends.append(sent)  # known before its first line is acked
                    for command in layer:
                        yield command
                    progress.done = i + 1
            finally:
                window.close()
        for line in plan.end_gcode():
            if strip_comment(line):
                yield strip_comment(line)

    return commands


async def stream(
    port: str,
    baud: int,
    commands: AsyncIterator[str],
    progress: Progress,
    bar: ProgressBar,
    end_gcode: tuple[str, ...],
    config: StreamerConfig | None = None,
) -> int:
    """Connect, stream every command, drain; Ctrl-C cancels with ``end_gcode``."""
    try:
        transport = await open_transport(port, baud)
    except TransportError as exc:
        raise UsageError(str(exc)) from exc
    loop = asyncio.get_running_loop()
    async with Streamer(transport, config or StreamerConfig()) as link:
        interrupted = asyncio.Event()

        async def follow(acks: AckChannel) -> None:
            async for _ack in acks:
                progress.acked += 1
                bar.draw(progress)

        def on_temperature(report: Response) -> None:
            progress.hotend = report.temperatures.get("T") or report.temperatures.get("T0")

        def on_error(text: str) -> None:
            bar.stream.write(f"\nprinter: {text}\n")

        link.on_temperature, link.on_error = on_temperature, on_error
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(signal.SIGINT, interrupted.set)
        try:
            with link.acknowledgements() as acks:
                follower = asyncio.create_task(follow(acks), name="print-acks")
                await link.connect()
                sender = asyncio.create_task(_send_all(link, commands), name="print-sender")
                stop = asyncio.create_task(interrupted.wait(), name="print-interrupt")
                await asyncio.wait({sender, stop}, return_when=asyncio.FIRST_COMPLETED)
                if not sender.done():
                    await link.cancel(end_gcode)
                    with contextlib.suppress(StreamCancelled):
                        await sender
                    bar.draw(progress, final=True)
                    bar.stream.write("cancelled\n")
                    return 130
                stop.cancel()
                await sender
                await link.drain()
            await follower  # the channel closed: every acknowledgement counted
        except LinkError as exc:
            bar.draw(progress, final=True)
            bar.stream.write(f"hostd print: link failed: {exc}\n")
            return EXIT_FAILURE
        finally:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(signal.SIGINT)
        bar.draw(progress, final=True)
        stats = link.stats
        bar.stream.write(
            f"done: {progress.acked} lines in {time.monotonic() - bar.started:.1f} s, "
            f"{stats.resends} resend requests, {stats.lines_resent} lines resent\n"
        )
    return EXIT_OK


async def _send_all(link: Streamer, commands: AsyncIterator[str]) -> None:
    async for command in commands:
        await link.send(command)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd print``."""
    p.add_argument("file", metavar="FILE")
    p.add_argument("--port", required=True, metavar="PORT", help="serial device, or 'sim'")
    p.add_argument("--baud", type=int, default=250000, metavar="N")
    p.add_argument("--config", metavar="FILE", help="slicing settings for an STL")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])
    p.add_argument("--time-scale", type=float, default=0.0, metavar="X",
                   help="simulated printer speed with --port sim (0 = instant)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Stream ``args.file`` to ``args.port`` (``sim``: the in-process simulated printer)."""
    path = Path(args.file)
    if not path.is_file():
        raise UsageError(f"{path}: no such file")
    if args.baud < 0 or (args.baud == 0 and args.port != "sim"):
        raise UsageError(f"--baud {args.baud}: must be a positive speed")
    suffix = path.suffix.lower()
    if suffix == ".stl":
        from hostd.app.commands.slice import load_plan, load_settings

        settings, bed = load_settings(args.config, args.set)
        plan = load_plan(str(path), settings, bed)
        progress = Progress("layers", plan.layer_count)
        commands = stl_commands(plan)
        end_gcode = tuple(c for c in map(strip_comment, plan.end_gcode()) if c)
    elif suffix in GCODE_SUFFIXES:
        total, commands = gcode_commands(path)
        progress = Progress("lines", total)
        end_gcode = CANCEL_GCODE  # what the daemon's cancelled jobs get too
    else:
        raise UsageError(f"{path}: not a G-code file ({', '.join(GCODE_SUFFIXES)}) or an STL")
    bar = ProgressBar(sys.stderr, enabled=not args.quiet)
    sim: SimulatedPrinter | None = None
    port = args.port
    if port == "sim":
        try:
            sim = SimulatedPrinter(SimulatorConfig(time_scale=args.time_scale, baud=args.baud))
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
        port = sim.start()
    try:
        return asyncio.run(stream(port, args.baud or 250000, commands(progress), progress,
                                  bar, end_gcode))
    finally:
        if sim is not None:
            sim.stop()
