"""The `hostd` command line: builds the parser from the registry of subcommands
(:mod:`hostd.app.commands`) and hands the one asked to its module."""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import importlib
import os
import sys
import threading
from collections.abc import Iterator, Sequence
from types import ModuleType

from hostd.app.commands import COMMANDS

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


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of every subcommand, or, given ``command``, of that one alone
    (``""``: of none, for ``hostd --help`` and a command line naming no subcommand).

    Every registered subcommand is listed (``hostd --help`` is the same either way);
    each gets its arguments from its module's ``add_arguments``, which is imported for
    it. Given ``command``, the others get none, and their modules are not imported.
    """
    parser = argparse.ArgumentParser(
        prog="hostd",
        description="3D-printer host with a just-in-time implicit slicer.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, registered in COMMANDS.items():
        p = sub.add_parser(name, help=registered.help)
        if command is None or command == name:
            _import_command(registered.module).add_arguments(p)
    return parser


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Imports made in the block run with the cyclic garbage collector paused, and what
    they made is then frozen out of later collections.

    An import makes only objects that live on (modules, classes, functions), yet
    the collector went over them dozens of times while numpy and the slicer were
    imported (a tenth of the import time). A command whose module stays light for
    its arguments (``hostd slice``) imports its heavy modules in such a block.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
        gc.freeze()
    finally:
        if enabled:
            gc.enable()


def _import_command(name: str) -> ModuleType:
    """The subcommand's module, imported with the cyclic garbage collector paused
    (:func:`collector_paused`)."""
    if name in sys.modules:
        return sys.modules[name]
    with collector_paused():
        return importlib.import_module(name)


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: runs one subcommand and returns the process exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    named = argv[0] if argv and argv[0] in COMMANDS else None
    if named is not None and named not in _BLAS_POOL_KEPT:
        # before the command's module (and numpy with it) is imported for its arguments
        for variable in _BLAS_VARIABLES:
            os.environ.setdefault(variable, "1")
    args = build_parser(named or "").parse_args(argv)
    module = _import_command(COMMANDS[args.command].module)
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
    from hostd.app.cli import entry as package_entry

    package_entry()
