"""The job folder's file rules: which names are jobs, and moving outcomes without overwriting."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

ACCEPTED_SUFFIXES = (".stl", ".gcode")
# a load case taken with its model; one whose model never comes is failed on its own
LOAD_SUFFIX = ".load.toml"
IGNORED_SUFFIXES = (".part", "~", ".swp", ".swx", ".tmp", ".crdownload", ".partial")
# every file an outcome may hold for one job stem; a stem is free when none exists
OUTCOME_SUFFIXES = (".stl", ".gcode", ".toml", ".error.txt", ".summary.txt")


def is_ignored(name: str) -> bool:
    """True for hidden and temporary names (dotfiles, ``.part``, ``~``, ``.swp``, ``.tmp``)."""
    lower = name.lower()
    return name.startswith(".") or lower.endswith(IGNORED_SUFFIXES)


def is_job_name(name: str) -> bool:
    """True for a name the watcher passes to the intake: ``.stl``, ``.gcode`` or a load
    case (``.load.toml``), not ignored."""
    return not is_ignored(name) and name.lower().endswith((*ACCEPTED_SUFFIXES, LOAD_SUFFIX))


def split_name(name: str) -> tuple[str, str]:
    """``part.stl`` -> (``part``, ``.stl``); the suffix is returned lower-case."""
    stem, suffix = os.path.splitext(name)
    return stem, suffix.lower()


def free_stem(folder: Path, stem: str) -> str:
    """``stem``, or ``stem-1``, ``stem-2``... the first for which no outcome file exists."""
    folder.mkdir(parents=True, exist_ok=True)
    candidate = stem
    number = 0
    while any((folder / f"{candidate}{suffix}").exists() or
              (folder / f"{candidate}{suffix}").is_symlink() for suffix in OUTCOME_SUFFIXES):
        number += 1
        candidate = f"{stem}-{number}"
    return candidate


def move(source: Path, target: Path) -> Path:
    """Move a file, link or directory to ``target`` (rename when possible, else copy)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.replace(source, target)
    except OSError:
        shutil.move(str(source), str(target))
    return target


def write_text(path: Path, text: str) -> Path:
    """Write a small text file atomically (aside, then rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.part")
    partial.write_text(text, encoding="utf-8")
    os.replace(partial, path)
    return path


def leaves_folder(path: Path, folder: Path) -> bool:
    """True when ``path`` is a link whose target lies outside ``folder``."""
    if not path.is_symlink():
        return False
    target = Path(os.path.realpath(path))
    root = Path(os.path.realpath(folder))
    return root not in target.parents
