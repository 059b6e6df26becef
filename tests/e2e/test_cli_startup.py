"""The command line's start-up: a subcommand is imported with the garbage collector paused."""

from __future__ import annotations

import subprocess
import sys

_PROBE = """
import gc, sys
from hostd.app import cli
gc.disable()
cli._import_command("hostd.app.commands.history")
kept_off = not gc.isenabled()
gc.enable()
before = gc.get_freeze_count()
module = cli._import_command("hostd.app.commands.tailor")
print(kept_off, gc.isenabled(), gc.get_freeze_count() > before, "numpy" in sys.modules,
      module is sys.modules["hostd.app.commands.tailor"],
      cli._import_command("hostd.app.commands.tailor") is module)
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
    from hostd.app.cli import build_parser
    from hostd.app.commands import COMMANDS

    argv = ["slice", "m.stl", "-o", "o.gcode", "--set", "infill.density=0.3", "--jobs", "2"]
    assert vars(build_parser("slice").parse_args(argv)) == vars(build_parser().parse_args(argv))
    assert build_parser("slice").format_help() == build_parser().format_help()
    assert set(COMMANDS) >= {"run", "slice", "print", "simulate", "tui", "status"}
    out = subprocess.run([sys.executable, "-m", "hostd", "slice", "m.stl", "-o", "o.gcode",
                          "--jobs", "0"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert "at least 1 process slices" in out.stderr
    # each subcommand built alone still parses its own help
    for name in COMMANDS:
        sub = subprocess.run([sys.executable, "-m", "hostd", name, "--help"],
                             capture_output=True, text=True, timeout=120)
        assert sub.returncode == 0
        assert f"usage: hostd {name}" in sub.stdout


_HELP_LOADS = """
import contextlib, io, sys
from hostd.app import cli
help_text = io.StringIO()
with contextlib.suppress(SystemExit), contextlib.redirect_stdout(help_text):
    cli.main(sys.argv[1:])
assert "usage: hostd" in help_text.getvalue()
loaded = sorted(m for m in sys.modules if m.split(".")[0] in ("hostd", "slicer", "numpy"))
print(" ".join(loaded))
"""

_SLICE_PAUSES = """
import gc, sys
from hostd.app import cli
from hostd.app.commands import slice as command
frozen = []
class Stop(Exception):
    pass
def stop():
    frozen.append((gc.isenabled(), gc.get_freeze_count() > 0, "slicer.plan" in sys.modules))
    raise Stop
command.return_freed_memory = stop
try:
    cli.main(["slice", "m.stl", "-o", "o.gcode"])
except Stop:
    pass
print(*frozen[0])
"""


def test_slice_help_loads_its_light_module_and_no_slicer() -> None:
    """``hostd slice --help`` imports the registry and the slice command's module, whose
    arguments it prints, but neither the slicer nor numpy."""
    out = subprocess.run([sys.executable, "-c", _HELP_LOADS, "slice", "--help"],
                         capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["hostd", "hostd.app", "hostd.app.cli", "hostd.app.commands",
                                  "hostd.app.commands.slice"]


def test_hostd_help_lists_every_command_and_imports_none() -> None:
    out = subprocess.run([sys.executable, "-c", _HELP_LOADS, "--help"],
                         capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["hostd", "hostd.app", "hostd.app.cli", "hostd.app.commands"]


def test_slice_imports_the_slicer_with_the_collector_paused_then_frozen() -> None:
    """By the time ``hostd slice`` starts its work the slicer is imported, the collector is
    on again and what the imports made is frozen out of collections."""
    out = subprocess.run([sys.executable, "-c", _SLICE_PAUSES], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.split() == ["True", "True", "True"]
