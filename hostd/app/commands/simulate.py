"""`hostd simulate`: serve the simulated Marlin printer on a pseudo-terminal until stopped."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from types import FrameType

from drivers.sim.config import FAULT_KINDS
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig
from hostd.app.cli import UsageError
from slicer.options import Choice, Number, SettingError, parse_assignment


def parse_faults(specs: list[str]) -> dict[str, float]:
    """``["drop_ok=0.01", ...]`` -> ``{"p_drop_ok": 0.01}``; raises UsageError when malformed
    (KIND=P, KIND one of the simulator's fault kinds, P a probability: ``slicer.options``)."""
    faults: dict[str, float] = {}
    for spec in specs:
        if "=" not in spec:
            raise UsageError(f"--fault {spec!r}: expected KIND=P with KIND one of "
                             + ", ".join(FAULT_KINDS))
        try:
            kind, value = parse_assignment(spec)
            kind = Choice(FAULT_KINDS).check(kind, kind)
            faults[f"p_{kind}"] = Number(0.0, 1.0).check(kind, value)
        except SettingError as exc:
            raise UsageError(f"--fault {spec!r}: {exc.reason}") from exc
    return faults


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd simulate``."""
    p.add_argument("--time-scale", type=float, default=1.0, metavar="X")
    p.add_argument("--baud", type=int, default=250000, metavar="N",
                   help="wire speed to emulate (0 = unlimited)")
    p.add_argument("--latency-ms", type=float, default=0.0, metavar="X",
                   help="one-way link latency added to every byte in each direction"
                        " (USB frames, firmware loop; e.g. 1, or 16 for an FTDI default)")
    p.add_argument("--log", metavar="FILE", help="append every executed line to FILE")
    p.add_argument("--advanced-ok", action="store_true", help="answer ok N.. P.. B..")
    p.add_argument("--fault", metavar="KIND=P", action="append", default=[],
                   help="inject a fault with probability P (repeatable): corrupt_rx, corrupt_tx,"
                        " drop_ok, resend, busy, reset, disconnect")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of the faults")
    p.add_argument("--link", metavar="PATH",
                   help="keep a symlink at PATH to the current pseudo-terminal")


def run(args: argparse.Namespace) -> int:
    """Print the device path on the first line of stdout, then serve until SIGINT/SIGTERM."""
    try:
        config = SimulatorConfig(
            time_scale=args.time_scale,
            baud=args.baud,
            latency_s=getattr(args, "latency_ms", 0.0) / 1000.0,
            log_path=args.log,
            keep_executed=False,  # served until stopped: the log, not memory, keeps them
            advanced_ok=args.advanced_ok,
            seed=getattr(args, "seed", 0),
            link_path=getattr(args, "link", None),
            **parse_faults(getattr(args, "fault", [])),
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from exc
    stop = threading.Event()

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with SimulatedPrinter(config) as sim:
            print(sim.path, flush=True)
            print(
                f"simulated Marlin printer: time scale {config.time_scale:g}, "
                f"baud {config.baud or 'unlimited'}, "
                f"latency {config.latency_s * 1000.0:g} ms; Ctrl-C to stop",
                file=sys.stderr,
                flush=True,
            )
            stop.wait()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
