"""What the daemon tests share: small models to print, requests over the control socket,
a waiter for a layer printing, and the commands a print is expected to send."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import trimesh

from drivers.link.protocol import strip_comment
from hostd.api import ControlClient, Snapshot
from slicer.output.entry import entered, last_xy
from slicer.plan import SlicePlan


def two_bodies(path: Path) -> Path:
    """Two 20 x 20 x 10 mm boxes side by side in one STL (two bodies)."""
    left = trimesh.creation.box((20.0, 20.0, 10.0))
    left.apply_translation((-20.0, 0.0, 5.0))
    right = trimesh.creation.box((20.0, 20.0, 10.0))
    right.apply_translation((20.0, 0.0, 5.0))
    trimesh.util.concatenate([left, right]).export(path)
    return path


def small_box(path: Path) -> Path:
    """A 10 x 10 x 3 mm box: a short job."""
    trimesh.creation.box((10.0, 10.0, 3.0)).export(path)
    return path


def command(socket: Path, cmd: str, **args: Any) -> dict[str, Any]:
    async def ask() -> dict[str, Any]:
        async with ControlClient(str(socket)) as client:
            return await client.request(cmd, **args)

    return asyncio.run(ask())


def status(socket: Path) -> Snapshot:
    return Snapshot.from_dict(command(socket, "status")["status"])


def printing_layer(socket: Path, at_least: int):
    """A waiter: the status once layer ``at_least`` (from 0) is printing, the ones below done."""
    def check():
        snap = status(socket)
        if snap.state == "printing" and snap.job is not None and snap.job.layer >= at_least:
            return snap
        return None
    return check


def commands(lines: list[str]) -> list[str]:
    return [c for c in map(strip_comment, lines) if c]


def layer_commands(plan_of: Callable[[int], SlicePlan],
                   excluded_of: Callable[[int], frozenset[int]], count: int) -> list[str]:
    """The commands of layers ``0..count-1`` as the daemon joins them: each layer's first
    travel goes around the cancelled bodies from where the layer before ended."""
    out: list[str] = []
    at = None
    for index in range(count):
        plan, left_out = plan_of(index), excluded_of(index)
        lines, _ = entered(plan.layer_gcode(index, left_out), at,
                           plan.entry_region(index, left_out), plan.settings.acceleration)
        at = last_xy(lines) if last_xy(lines) is not None else at
        out += commands(lines)
    return out


def daemon_pids(folder: Path) -> list[int]:
    """The processes running a daemon (``run`` in their command line) in ``folder``."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cwd = os.readlink(entry / "cwd")
                cmd = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if cwd == str(folder) and b"run" in cmd:
                pids.append(int(entry.name))
    return pids
