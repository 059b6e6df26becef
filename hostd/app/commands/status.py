"""`hostd status`: one status snapshot from the running daemon, as text or JSON."""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from typing import Any

from hostd.api import ControlClient, ControlError, Snapshot, duration
from hostd.app.cli import EXIT_FAILURE, EXIT_OK, UsageError
from hostd.app.commands.target import add_target, socket_path


async def fetch_status(path: str) -> dict[str, Any]:
    """The daemon's current snapshot as the JSON object it sent (raises ControlError)."""
    async with ControlClient(path) as client:
        reply = await client.request("status")
    return reply["status"]


def format_summary(snapshot: Snapshot) -> str:
    """A short human-readable summary of a snapshot (a few lines)."""
    printer = snapshot.printer
    link = "connected" if printer.connected else "not connected"
    hotend, bed = snapshot.temps.hotend, snapshot.temps.bed
    lines = [
        f"printer {printer.id} on {printer.port} ({link}): {snapshot.state}",
        f"hotend {hotend.actual:.1f}/{hotend.target:.0f} C,"
        f" bed {bed.actual:.1f}/{bed.target:.0f} C",
    ]
    job = snapshot.job
    if job is not None:
        lines.append(
            f"job {job.name} ({job.id}): layer {job.layer + 1} of {job.layers}, {job.progress:.1%},"
            f" elapsed {duration(job.elapsed_s, hours=True, unknown='unknown')},"
            f" ETA {duration(job.eta_s, hours=True, unknown='unknown')},"
            f" {job.layers_ready_ahead} layers ready ahead"
            + (f", filament {job.filament_used_mm / 1000:.2f} of about"
               f" {job.filament_total_mm / 1000:.2f} m"
               if job.filament_used_mm is not None and job.filament_total_mm is not None else "")
            + (f"; waiting for the stress {job.waiting_for}" if job.waiting_for else "")
        )
    if snapshot.queue:
        lines.append(f"queue ({len(snapshot.queue)}): " + ", ".join(snapshot.queue))
    for item in snapshot.interrupted:
        lines.append(
            f"interrupted: {item.name} ({item.id}) after layer {item.layer + 1};"
            f" resume with `hostd resume {item.id}`"
        )
    if snapshot.error:
        lines.append(f"error: {snapshot.error}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd status``."""
    p.add_argument("--json", action="store_true", help="print the raw JSON snapshot")
    add_target(p)


def run(args: argparse.Namespace) -> int:
    """Print the daemon's status; exit 1 when the daemon cannot be reached."""
    from hostd.config import ConfigError

    try:
        path = socket_path(args)
    except ConfigError as exc:
        raise UsageError(str(exc)) from exc
    try:
        data = asyncio.run(fetch_status(str(path)))
    except ControlError as exc:
        print(f"hostd status: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        print(json.dumps(data, sort_keys=True))
    else:
        print(format_summary(Snapshot.from_dict(data)))
    return EXIT_OK
