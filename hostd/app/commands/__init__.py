"""The `hostd` subcommands, registered here: the one registry the command line reads.

Each subcommand is one module of this package that brings its arguments and its work:
``add_arguments(parser)`` adds them to its ``argparse`` parser and ``run(args) -> int``
carries it out (raising ``hostd.app.cli.UsageError`` for bad usage or input). A new command
is a new module and one line below. The command line imports only the module of the
command asked (``hostd --help`` imports none of them); this package imports nothing.
"""

from __future__ import annotations


class Command:
    """A registered subcommand: the module that carries it out and its line in ``--help``."""

    __slots__ = ("help", "module")

    def __init__(self, module: str, help: str) -> None:
        self.module = module
        self.help = help

    def __repr__(self) -> str:
        return f"Command({self.module!r}, {self.help!r})"


# name -> command, in the order `hostd --help` lists them
COMMANDS: dict[str, Command] = {
    "run": Command("hostd.app.commands.run", "run the daemon (embedded default without --config)"),
    "slice": Command("hostd.app.commands.slice", "slice a model to a G-code file"),
    "tailor": Command("hostd.app.commands.tailor",
                      "Linear, Stress A and B G-codes at equal mass of a folder's model and load "
                      "case, pictures, predicted moduli"),
    "preview": Command("hostd.app.commands.preview", "draw one layer's toolpaths as PNG"),
    "tui": Command("hostd.app.commands.tui", "the terminal dashboard"),
    "status": Command("hostd.app.commands.status", "one status snapshot from the running daemon"),
    "resume": Command("hostd.app.commands.resume",
                      "resume an interrupted job from its last completed layer"),
    "history": Command("hostd.app.commands.history", "finished jobs and totals (newest first)"),
    "reprint": Command("hostd.app.commands.reprint",
                       "queue a finished job again with its exact settings"),
    "print": Command("hostd.app.commands.print_file",
                     "stream a G-code file (or an STL) to a printer"),
    "simulate": Command("hostd.app.commands.simulate",
                        "run the simulated printer on a pseudo-terminal"),
    "farm": Command("hostd.app.commands.farm", "the farm queue: submit, list, requeue, material"),
}
