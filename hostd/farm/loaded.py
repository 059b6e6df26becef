"""The material loaded in the printer: ``[printer] material``, changed at run time by
``hostd farm material NAME`` (a small file in the state folder the daemon reads before
each take)."""

from __future__ import annotations

from pathlib import Path

from hostd.config import Config
from hostd.jobs.jobfolder import write_text

MATERIAL_FILE = "farm-material"


def material_file(config: Config) -> Path:
    """Where the run-time material is kept."""
    return config.state.folder / MATERIAL_FILE


def loaded_material(config: Config) -> str:
    """The material loaded now: the run-time choice if one was made, else the config's."""
    try:
        text = material_file(config).read_text(encoding="utf-8").strip()
    except OSError:
        return config.printer.material
    return text or config.printer.material


def load_material(config: Config, material: str) -> Path:
    """Record that ``material`` is loaded now (written atomically); returns the file."""
    material = material.strip()
    if not material or not material.isprintable():
        raise ValueError(f"{material!r} is not a material name")
    return write_text(material_file(config), material + "\n")
