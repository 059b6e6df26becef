"""`hostd resume JOB`: ask the running daemon to resume an interrupted job."""

from __future__ import annotations

import argparse
import asyncio

from hostd.api import ControlClient, ControlError
from hostd.app.cli import EXIT_FAILURE, EXIT_OK, UsageError
from hostd.app.commands.target import add_target, socket_path
from hostd.config import ConfigError


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd resume``."""
    p.add_argument("job", metavar="JOB")
    add_target(p)


def run(args: argparse.Namespace) -> int:
    """Send ``resume_job`` over the control socket; exit 1 when no daemon answers."""
    try:
        path = socket_path(args)
    except ConfigError as exc:
        raise UsageError(f"bad configuration: {exc}") from exc
    if not path.exists():
        print(f"hostd resume: no daemon is running (no control socket at {path}); "
              "start it with `hostd run`, then resume")
        return EXIT_FAILURE
    try:
        reply = asyncio.run(_resume(str(path), args.job))
    except ControlError as exc:
        if "cannot reach" in str(exc):
            print(f"hostd resume: no daemon is running: {exc}")
            return EXIT_FAILURE
        raise UsageError(str(exc)) from exc
    print(f"job {reply.get('job')} ({reply.get('name')}) queued to resume at layer "
          f"{int(reply.get('from_layer') or 0) + 1}")
    return EXIT_OK


async def _resume(path: str, job: str) -> dict:
    async with ControlClient(path) as client:
        return await client.request("resume_job", job=job)
