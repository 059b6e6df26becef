"""`hostd history`: finished jobs and totals from the print history, as text, JSON or CSV."""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path

from hostd.api import duration
from hostd.app.cli import EXIT_OK, UsageError
from hostd.config import ConfigError, load_config
from hostd.publishing.history import HISTORY_FILE, History, PrintRecord

CSV_COLUMNS = ("job_id", "name", "outcome", "reason", "started", "ended", "print_s", "total_s",
               "layers", "layers_done", "filament_mm", "filament_g", "infill_field", "retunes",
               "cancelled", "model")


def open_history(args: argparse.Namespace) -> History:
    """The configured state folder's history file, read only (UsageError when there is none)."""
    try:
        config = load_config(getattr(args, "config", None))
    except ConfigError as exc:
        raise UsageError(f"bad configuration: {exc}") from exc
    path = Path(config.state.folder) / HISTORY_FILE
    try:
        return History(path, readonly=True)
    except (FileNotFoundError, OSError) as exc:
        raise UsageError(f"{exc}; the daemon writes it once it has run") from exc


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd history``."""
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--json", action="store_true", help="every field of every job, and totals")
    fmt.add_argument("--csv", action="store_true", help="one row per job")
    p.add_argument("--limit", type=int, metavar="N", help="the last N jobs only")
    p.add_argument("--config", metavar="FILE", help="daemon configuration (its state folder)")


def run(args: argparse.Namespace) -> int:
    """Print the last ``--limit`` jobs (newest first) and the totals."""
    if args.limit is not None and args.limit < 1:
        raise UsageError(f"--limit must be 1 or more, got {args.limit}")
    history = open_history(args)
    try:
        records = history.records(args.limit)
        totals = history.totals()
    finally:
        history.close()
    if args.json:
        json.dump({"totals": totals, "jobs": [asdict(r) for r in records]}, sys.stdout, indent=2)
        print()
    elif args.csv:
        writer = csv.writer(sys.stdout)
        writer.writerow(CSV_COLUMNS)
        for record in records:
            row = asdict(record)
            writer.writerow([json.dumps(row[c]) if isinstance(row[c], list) else row[c]
                             for c in CSV_COLUMNS])
    else:
        print(format_table(records, totals))
    return EXIT_OK


def format_table(records: list[PrintRecord], totals: dict) -> str:
    """Records one per line, then the totals."""
    lines = [f"{'job':>5}  {'ended':16}  {'outcome':9}  {'time':>8}  {'filament':>9}  name"]
    for r in records:
        ended = time.strftime("%Y-%m-%d %H:%M", time.localtime(r.ended))
        extra = f"  ({r.reason})" if r.reason else ""
        spent = duration(r.print_s, hours=True)
        lines.append(f"{r.job_id:>5}  {ended:16}  {r.outcome:9}  {spent:>8}  "
                     f"{r.filament_g:7.1f} g  {r.name}{extra}")
    rate = totals["success_rate"]
    total, longest = (duration(totals[k], hours=True) for k in ("total_print_s", "longest_print_s"))
    lines.append(
        f"{totals['jobs']} jobs ({totals['done']} done, {totals['failed']} failed, "
        f"{totals['cancelled']} cancelled), success rate "
        f"{'--' if rate is None else f'{rate * 100:.0f} %'}; print time "
        f"{total}, longest {longest}; "
        f"filament {totals['total_filament_mm'] / 1000:.2f} m ({totals['total_filament_g']:.1f} g)"
    )
    return "\n".join(lines)
