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
