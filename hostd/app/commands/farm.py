"""`hostd farm`: submit models to the farm queue, list it, give a held job back, set the
loaded material."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from hostd.app.cli import EXIT_FAILURE, EXIT_OK, UsageError
from hostd.config import Config, ConfigError, FarmConfig, load_config


def _config(args: argparse.Namespace) -> tuple[FarmConfig, Config | None]:
    """The connection: ``[farm]`` of ``--config`` (if given), then the command's options."""
    daemon: Config | None = None
    farm = FarmConfig()
    if args.config:
        try:
            daemon = load_config(args.config)
        except ConfigError as exc:
            raise UsageError(str(exc)) from exc
        farm = daemon.farm
    changes: dict[str, Any] = {}
    if args.servers:
        servers = tuple(s.strip() for s in args.servers.split(",") if s.strip())
        if not servers:
            raise UsageError("--servers: give at least one nats://HOST:PORT")
        changes["servers"] = servers
    if args.user:
        changes["user"] = args.user
    password = args.password if args.password is not None else \
        os.environ.get("HOSTD_FARM_PASSWORD")
    if password is not None:
        changes["password"] = password
    if args.tls:
        changes["tls"] = True
    if args.cafile:
        changes["ca_file"] = args.cafile
    return replace(farm, **changes), daemon


def _settings(assignments: list[str]) -> dict[str, Any]:
    """``--set KEY=VALUE`` as flat keys, checked against the slicer's settings."""
    from slicer.settings import SettingsError, SliceSettings, parse_assignment

    try:
        overrides = dict(parse_assignment(text) for text in assignments)
        SliceSettings.from_mapping(overrides)
    except SettingsError as exc:
        raise UsageError(f"--set {exc}") from exc
    return overrides


async def _submit(farm: FarmConfig, args: argparse.Namespace) -> list[str]:
    from hostd.farm.needs import NeedsError, parse_needs
    from hostd.farm.queue import FarmQueue

    try:
        needs = parse_needs(args.needs or "")
    except NeedsError as exc:
        raise UsageError(f"--needs {exc}") from exc
    settings = _settings(args.set)
    path = Path(args.model)
    try:
        data = await asyncio.to_thread(path.read_bytes)
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from exc
    queue = await FarmQueue.open(farm, "hostd-farm-submit")
    try:
        return await queue.submit(path.name, data, args.copies, settings, needs,
                                  max_bytes=farm.max_bytes)
    finally:
        await queue.close()


async def _list(farm: FarmConfig) -> list[dict[str, Any]]:
    from hostd.farm.queue import FarmQueue

    queue = await FarmQueue.open(farm, "hostd-farm-list")
    try:
        return [row.to_dict() for row in await queue.listing()]
    finally:
        await queue.close()


async def _requeue(farm: FarmConfig, job_id: str, force: bool) -> None:
    from hostd.farm.queue import FarmQueue

    queue = await FarmQueue.open(farm, "hostd-farm-requeue")
    try:
        await queue.requeue(job_id, force)
    finally:
        await queue.close()


def _table(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return "the farm queue is empty"
    lines = []
    for row in rows:
        who = f" on {row['printer']}" if row["printer"] else ""
        why = f": {row['reason']}" if row["reason"] else ""
        lines.append(f"{row['id']}  {row['state']:<11} {row['name']}{who}{why}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
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


def run(args: argparse.Namespace) -> int:
    """Carry out one farm action; exit 1 when the farm refuses it or cannot be reached."""
    from hostd.farm.model import Refused
    from hostd.farm.queue import FarmError

    farm, daemon = _config(args)
    try:
        if args.action == "submit":
            if args.copies < 1:
                raise UsageError("--copies must be at least 1")
            ids = asyncio.run(_submit(farm, args))
            print(json.dumps(ids) if args.json else "\n".join(ids))
        elif args.action == "list":
            rows = asyncio.run(_list(farm))
            print(json.dumps(rows) if args.json else _table(rows))
        elif args.action == "requeue":
            asyncio.run(_requeue(farm, args.job, args.force))
            print(f"{args.job} waiting again")
        elif args.action == "material":
            from hostd.farm.loaded import load_material

            if daemon is None:
                raise UsageError("material needs --config (the printer's daemon configuration)")
            try:
                load_material(daemon, args.material)
            except ValueError as exc:
                raise UsageError(str(exc)) from exc
            print(f"{daemon.printer.id}: {args.material.strip()} loaded")
    except (Refused, FarmError) as exc:
        print(f"hostd farm {args.action}: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK
