"""`hostd simulate`: serve the simulated Marlin printer on a pseudo-terminal until stopped."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from types import FrameType

from drivers.simulator import SimulatedPrinter, SimulatorConfig


def run(args: argparse.Namespace) -> int:
    """Print the device path on the first line of stdout, then serve until SIGINT/SIGTERM."""
    config = SimulatorConfig(
        time_scale=args.time_scale,
        baud=args.baud,
        log_path=args.log,
        advanced_ok=args.advanced_ok,
    )
    stop = threading.Event()

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with SimulatedPrinter(config) as sim:
            print(sim.path, flush=True)
            print(
                f"simulated Marlin printer: time scale {config.time_scale:g}, "
                f"baud {config.baud or 'unlimited'}; Ctrl-C to stop",
                file=sys.stderr,
                flush=True,
            )
            stop.wait()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
