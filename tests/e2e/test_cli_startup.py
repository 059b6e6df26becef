"""The command line's start-up: a subcommand is imported with the garbage collector paused."""

from __future__ import annotations

import subprocess
import sys

_PROBE = """
import gc, sys
from hostd import cli
gc.disable()
cli._import_command("hostd.commands.history")
kept_off = not gc.isenabled()
gc.enable()
before = gc.get_freeze_count()
module = cli._import_command("hostd.commands.slice")
print(kept_off, gc.isenabled(), gc.get_freeze_count() > before, "numpy" in sys.modules,
      module is sys.modules["hostd.commands.slice"],
      cli._import_command("hostd.commands.slice") is module)
"""


def test_subcommand_import_pauses_and_restores_the_collector() -> None:
    """The collector's state is the caller's again after the import (off stays off, on
    comes back on); the imported objects are frozen out of later collections; a module
    imported already is returned as it is."""
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.split() == ["True"] * 6


def test_a_parser_built_for_one_subcommand_parses_it_as_the_whole_parser_does() -> None:
    """Built for ``slice``, the parser gives the same namespace for a slice command line,
    still knows every subcommand (``hostd --help`` is unchanged) and refuses a bad
    option of the subcommand it was built for."""
    from hostd.cli import _SUBCOMMANDS, build_parser

    argv = ["slice", "m.stl", "-o", "o.gcode", "--set", "infill.density=0.3", "--jobs", "2"]
    assert vars(build_parser("slice").parse_args(argv)) == vars(build_parser().parse_args(argv))
    assert build_parser("slice").format_help() == build_parser().format_help()
    assert set(_SUBCOMMANDS) >= {"run", "slice", "print", "simulate", "tui", "status"}
    out = subprocess.run([sys.executable, "-m", "hostd", "slice", "m.stl", "-o", "o.gcode",
                          "--jobs", "0"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert "at least 1 process slices" in out.stderr
    # each subcommand built alone still parses its own help
    for name in _SUBCOMMANDS:
        sub = subprocess.run([sys.executable, "-m", "hostd", name, "--help"],
                             capture_output=True, text=True, timeout=120)
        assert sub.returncode == 0
        assert f"usage: hostd {name}" in sub.stdout
