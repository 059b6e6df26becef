"""The `hostd` command line: parses arguments and hands each subcommand to its module."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import importlib
import os
import sys
import threading
from collections.abc import Callable, Sequence
from types import ModuleType

# numpy's BLAS on one thread for the one-shot commands, unless the environment says
# otherwise; set before numpy is first imported (each subcommand's module imports
# it). The slicer's arrays are small and gain nothing from a BLAS thread pool,
# whose start spins a second core for some 60 ms while numpy loads. The daemon and
# `hostd tailor` keep the pool: their finite-element solves gain from it (the
# dogbone's 0.95 s on two threads, 1.10 s on one) and a daemon starts once.
_BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_BLAS_POOL_KEPT = frozenset({"run", "tailor"})

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2


class UsageError(Exception):
    """Bad usage or bad input: reported as one line on stderr with exit code 2."""


def _add_target(parser: argparse.ArgumentParser) -> None:
    """Options that locate a running daemon: its config file or its control socket."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE", help="daemon configuration (TOML)")
    group.add_argument("--socket", metavar="PATH", help="the daemon's control socket")


def _jobs(text: str) -> int:
    """``--jobs N``: a whole number of processes, at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: at least 1 process slices")
    return value


def _run_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd run``."""
    p.add_argument("--config", metavar="FILE", help="configuration file (TOML)")


def _slice_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd slice``."""
    p.add_argument("model", metavar="MODEL")
    p.add_argument("-o", "--output", metavar="OUT.gcode", required=True)
    p.add_argument("--config", metavar="FILE", help="take [slicing] and [printer] from FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                   help="override one slicing setting (repeatable)")
    p.add_argument("--load", metavar="FILE",
                   help="load case (TOML): stress infill from the built-in analysis")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--profile", action="store_true",
                   help="slice in one process and print the time of each stage")
    p.add_argument("--jobs", type=_jobs, metavar="N",
                   help="processes slicing layers (default: the CPUs; 1: this one only)")


def _tailor_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd tailor``."""
    p.add_argument("folder", metavar="DIR", help="holds NAME.stl, NAME.load.toml (NAME.toml)")
    p.add_argument("-o", "--output", metavar="OUTDIR", help="where to write (default DIR/out)")
    p.add_argument("--optimal", action="store_true",
                   help="also infill.stress = optimal (optimised density at equal mass)")
    p.add_argument("--config", metavar="FILE", help="take [slicing] and [printer] from FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])


def _preview_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd preview``."""
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--layer", type=int, required=True, metavar="N",
                   help="layer N of the model, counted from 1 as everywhere (-1: the last)")
    p.add_argument("-o", "--output", metavar="OUT.png", required=True)
    p.add_argument("--field", action="store_true", help="draw the infill field and its level sets")
    p.add_argument("--config", metavar="FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])


def _tui_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd tui``."""
    group = p.add_mutually_exclusive_group()
    group.add_argument("--config", metavar="FILE")
    group.add_argument("--socket", metavar="PATH")
    group.add_argument("--mqtt", metavar="HOST[:PORT]",
                       help="the fleet view on a broker (a cluster: HOST:PORT,HOST:PORT,...)")
    p.add_argument("--username", default="", help="broker user name (with --mqtt)")
    p.add_argument("--password", default=None,
                   help="broker password (with --mqtt; default: $HOSTD_MQTT_PASSWORD)")
    p.add_argument("--tls", action="store_true", help="connect to the broker over TLS")
    p.add_argument("--cafile", metavar="FILE",
                   help="with --tls: the CA (PEM) of the broker's certificate (default: system's)")
    p.add_argument("--certfile", metavar="FILE",
                   help="with --tls: this client's certificate (PEM), with --keyfile")
    p.add_argument("--keyfile", metavar="FILE", help="with --tls: the key of --certfile (PEM)")
    p.add_argument("--farm", metavar="URL,...",
                   help="with --mqtt: the farm queue on these NATS servers beside the printers")
    p.add_argument("--redraw-s", metavar="S", default=None,
                   help="for a slow link: draw the layer picture and the event log (and the "
                        "fleet table) at most once every S seconds (default: "
                        "$HOSTD_TUI_REDRAW_S, else as the status comes)")


def _status_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd status``."""
    p.add_argument("--json", action="store_true", help="print the raw JSON snapshot")
    _add_target(p)


def _resume_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd resume``."""
    p.add_argument("job", metavar="JOB")
    _add_target(p)


def _history_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd history``."""
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true", help="every field of every job, and totals")
    fmt.add_argument("--csv", action="store_true", help="one row per job")
    p.add_argument("--limit", type=int, metavar="N", help="the last N jobs only")
    p.add_argument("--config", metavar="FILE", help="daemon configuration (its state folder)")


def _reprint_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd reprint``."""
    p.add_argument("job", metavar="JOB", help="job id, or name (the newest with that name)")
    p.add_argument("--config", metavar="FILE", help="daemon configuration (TOML)")


def _print_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd print``."""
    p.add_argument("file", metavar="FILE")
    p.add_argument("--port", required=True, metavar="PORT", help="serial device, or 'sim'")
    p.add_argument("--baud", type=int, default=250000, metavar="N")
    p.add_argument("--config", metavar="FILE", help="slicing settings for an STL")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])
    p.add_argument("--time-scale", type=float, default=0.0, metavar="X",
                   help="simulated printer speed with --port sim (0 = instant)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _simulate_arguments(p: argparse.ArgumentParser) -> None:
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


def _farm_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd farm``."""
    p.add_argument("--config", metavar="FILE", help="take [farm] (and the state folder) from FILE")
    p.add_argument("--servers", metavar="URL,...", help="the cluster's NATS URLs")
    p.add_argument("--user", default="", help="NATS user name")
    p.add_argument("--password", default=None,
                   help="NATS password (default: $HOSTD_FARM_PASSWORD)")
    p.add_argument("--tls", action="store_true", help="connect over TLS")
    p.add_argument("--cafile", metavar="FILE", help="with --tls: the servers' CA (PEM)")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    submit = actions.add_parser("submit", help="offer a model to the farm's printers")
    submit.add_argument("model", metavar="MODEL.stl")
    submit.add_argument("--copies", type=int, default=1, metavar="N")
    submit.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                        help="a slicing setting over each printer's own (repeatable)")
    submit.add_argument("--needs", metavar="KEY=VALUE,...",
                        help="material=PETG,nozzle=0.4,bed=220x220 (any of them)")
    submit.add_argument("--json", action="store_true", help="the job ids as a JSON list")
    listing = actions.add_parser("list", help="the queue: waiting, taken, printed, failed")
    listing.add_argument("--json", action="store_true")
    requeue = actions.add_parser("requeue", help="give a held or failed job back to the queue")
    requeue.add_argument("job", metavar="ID")
    requeue.add_argument("--force", action="store_true",
                         help="also a job whose printer fell silent without reporting it")
    material = actions.add_parser("material", help="the material loaded now (with --config)")
    material.add_argument("material", metavar="NAME")


# subcommand -> (its help, what adds its arguments), in the order `hostd --help` lists them
_SUBCOMMANDS: dict[str, tuple[str, Callable[[argparse.ArgumentParser], None]]] = {
    "run": ("run the daemon (embedded default without --config)", _run_arguments),
    "slice": ("slice a model to a G-code file", _slice_arguments),
    "tailor": ("Linear, Stress A and B G-codes at equal mass of a folder's model and load "
               "case, pictures, predicted moduli", _tailor_arguments),
    "preview": ("draw one layer's toolpaths as PNG", _preview_arguments),
    "tui": ("the terminal dashboard", _tui_arguments),
    "status": ("one status snapshot from the running daemon", _status_arguments),
    "resume": ("resume an interrupted job from its last completed layer", _resume_arguments),
    "history": ("finished jobs and totals (newest first)", _history_arguments),
    "reprint": ("queue a finished job again with its exact settings", _reprint_arguments),
    "print": ("stream a G-code file (or an STL) to a printer", _print_arguments),
    "simulate": ("run the simulated printer on a pseudo-terminal", _simulate_arguments),
    "farm": ("the farm queue: submit, list, requeue, material", _farm_arguments),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of every subcommand, or, given ``command``, of that one alone.

    The others are then listed (``hostd --help`` is the same) but get no
    arguments of their own: adding them all took some 10 ms of every ``hostd``
    start, mostly help formatters each asking for the terminal's size.
    """
    parser = argparse.ArgumentParser(
        prog="hostd",
        description="3D-printer host with a just-in-time implicit slicer.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (text, add_arguments) in _SUBCOMMANDS.items():
        p = sub.add_parser(name, help=text)
        if command is None or command == name:
            add_arguments(p)
    return parser


# subcommand -> module whose `run(args) -> int` carries it out
_COMMANDS = {
    "run": "hostd.commands.run",
    "slice": "hostd.commands.slice",
    "preview": "hostd.commands.preview",
    "tailor": "hostd.commands.tailor",
    "tui": "hostd.commands.tui",
    "status": "hostd.commands.status",
    "resume": "hostd.commands.resume",
    "print": "hostd.commands.print_file",
    "simulate": "hostd.commands.simulate",
    "history": "hostd.commands.history",
    "reprint": "hostd.commands.reprint",
    "farm": "hostd.commands.farm",
}


def _import_command(name: str) -> ModuleType:
    """The subcommand's module, imported with the cyclic garbage collector paused.

    An import makes only objects that live on (modules, classes, functions), yet
    the collector went over them dozens of times while numpy and the slicer were
    imported (a tenth of the import time); a first import is then frozen out of
    later collections as well.
    """
    if name in sys.modules:
        return sys.modules[name]
    enabled = gc.isenabled()
    gc.disable()
    try:
        module = importlib.import_module(name)
        gc.freeze()
    finally:
        if enabled:
            gc.enable()
    return module


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: runs one subcommand and returns the process exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    named = argv[0] if argv and argv[0] in _SUBCOMMANDS else None
    args = build_parser(named).parse_args(argv)
    if args.command not in _BLAS_POOL_KEPT:
        for variable in _BLAS_VARIABLES:
            os.environ.setdefault(variable, "1")
    module = _import_command(_COMMANDS[args.command])
    try:
        return int(module.run(args))
    except UsageError as exc:
        print(f"hostd {args.command}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        # the reader of our output left (`hostd slice ... | head -1`): say no more, and
        # let no flush at exit fail on the closed pipe
        with contextlib.suppress(OSError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return EXIT_FAILURE


def entry() -> None:
    """The console script (and ``python -m hostd``): :func:`main`, then the process ends.

    When the command has left no other thread running (``hostd slice``, ``preview``,
    ``status``...), the exit handlers run (``atexit``: logging, temporary files),
    stdout and stderr are flushed, and the process ends without tearing the
    interpreter down: freeing every module, array and geometry one by one took
    25 ms of a 0.3 s ``hostd slice``. Otherwise (threads still running) it exits
    as Python does, which waits for them.
    """
    code = main()
    if threading.active_count() > 1:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        # a closed stream or a reader gone: nothing more can be said
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    # run through the package module so that `UsageError` is the class commands raise
    from hostd.cli import entry as package_entry

    package_entry()
