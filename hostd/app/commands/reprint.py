"""`hostd reprint JOB`: drop a finished job's model into the job folder again, same settings."""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path
from typing import Any

from hostd.app.cli import EXIT_OK, UsageError
from hostd.app.commands.history import open_history
from hostd.config import load_config
from hostd.jobs.jobfolder import free_stem, split_name


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd reprint``."""
    p.add_argument("job", metavar="JOB", help="job id, or name (the newest with that name)")
    p.add_argument("--config", metavar="FILE", help="daemon configuration (TOML)")


def run(args: argparse.Namespace) -> int:
    """Copy the model kept in done/ or failed/ back with a ``NAME.toml`` of its exact settings.

    The new job's settings are the ones the old job started with (every key,
    so today's configuration does not change them); its retunes are listed
    but not replayed.
    """
    history = open_history(args)
    try:
        record = history.find(args.job)
    except KeyError as exc:
        raise UsageError(str(exc.args[0])) from exc
    finally:
        history.close()
    model = Path(record.model)
    if not model.is_file():
        raise UsageError(f"job {record.job_id} ({record.name}): its model is no longer at {model}")
    folder = load_config(getattr(args, "config", None)).jobs.folder
    stem, suffix = split_name(record.name)
    new_stem = free_stem(folder, stem)
    target = folder / f"{new_stem}{suffix}"
    if record.kind != "gcode":
        _write_atomic(folder / f"{new_stem}.toml", settings_toml(record.settings).encode())
    partial = folder / f".{new_stem}{suffix}.part"
    shutil.copyfile(model, partial)
    os.replace(partial, target)
    print(f"job {record.job_id} ({record.name}) dropped again as {target}")
    for first, changes in record.retunes:
        print(f"  not replayed: from layer {first}: {changes}")
    return EXIT_OK


def settings_toml(settings: dict[str, Any]) -> str:
    """Flat slicing settings as TOML (quoted dotted keys), one per line, in key order."""
    lines = ["# the exact settings of a job printed before (hostd reprint)"]
    for key in sorted(settings):
        value = settings[key]
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, int | float):
            text = repr(value)
        elif isinstance(value, str):
            text = json.dumps(value)
        else:
            raise UsageError(f"setting {key} = {value!r} cannot be written as TOML")
        lines.append(f"{json.dumps(key)} = {text}")
    return "\n".join(lines) + "\n"


def _write_atomic(path: Path, data: bytes) -> None:
    partial = path.with_name(f".{path.name}.part")
    partial.write_bytes(data)
    os.replace(partial, path)
