"""The commands of a G-code file and of the simulated printer's executed-line log."""

from __future__ import annotations

from pathlib import Path

from drivers.link.protocol import strip_comment
from slicer.output.annotate import is_annotation

# commands the streamer adds on its own (handshake, temperature reports)
HOUSEKEEPING = ("M110", "M105", "M115", "M503", "M155")


def commands_of(path: Path) -> list[str]:
    """The commands of a G-code file, comments, blank lines and the lines written for other
    hosts (M73 progress, object labels; never streamed) dropped."""
    with open(path, encoding="utf-8") as handle:
        return [c for c in map(strip_comment, handle) if c and not is_annotation(c)]


def executed_job_lines(log: Path) -> list[str]:
    """The simulator's executed-line log without the streamer's housekeeping commands."""
    with open(log, encoding="utf-8") as handle:
        lines = [line.rstrip("\n") for line in handle]
    return [line for line in lines if line and line.split()[0] not in HOUSEKEEPING]
