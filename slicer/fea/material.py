"""The printed material's measured properties (``[material]``) as slicing settings."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from slicer.settings import SettingsError, SliceSettings

# [material] key -> the slicing setting it sets
KEYS = {
    "youngs_modulus_mpa": "fea.youngs_modulus_mpa",
    "poisson_ratio": "fea.poisson_ratio",
    "density_g_cm3": "filament_density",
}


def material_settings(values: Mapping[str, Any], base: SliceSettings,
                      given: frozenset[str] = frozenset()) -> SliceSettings:
    """``base`` with a ``[material]`` table's modulus (MPa), Poisson's ratio and density
    (g/cm^3) in the settings the analysis and the masses read. ``given`` are the dotted
    slicing keys set elsewhere in the same file: one also set here is refused (the
    file would say two things). Raises SettingsError naming ``material.KEY``."""
    unknown = sorted(set(values) - set(KEYS))
    if unknown:
        raise SettingsError(f"material.{unknown[0]}",
                            f"unknown material key (allowed: {', '.join(KEYS)})")
    mapped = {}
    for key, value in values.items():
        if KEYS[key] in given:
            raise SettingsError(f"material.{key}",
                                f"also given as slicing setting {KEYS[key]}: give it once")
        mapped[KEYS[key]] = value
    try:
        return SliceSettings.from_mapping(mapped, base=base)
    except SettingsError as exc:
        name = next(k for k, v in KEYS.items() if v == exc.key)
        raise SettingsError(f"material.{name}", exc.reason) from exc


def file_settings(values: Mapping[str, Any], base: SliceSettings) -> SliceSettings:
    """``base`` with a job's ``NAME.toml``: slicing keys (nested or dotted) and an
    optional ``[material]`` table, one key given once. ``hostd tailor`` reads the
    folder's file and the daemon a dropped job's with it. Raises SettingsError naming
    the key (``material.KEY`` for the table's)."""
    rest = dict(values)
    material = rest.pop("material", {})
    if not isinstance(material, Mapping):
        raise SettingsError("material", "must be a [material] table")
    settings = SliceSettings.from_mapping(rest, base=base)
    return material_settings(material, settings, _dotted(rest))


def _dotted(values: Mapping[str, Any], prefix: str = "") -> frozenset[str]:
    """The dotted keys of a (nested) table: ``{"infill": {"density": 0.3}}`` gives
    ``infill.density``."""
    out: set[str] = set()
    for key, value in values.items():
        name = f"{prefix}{key}"
        out |= _dotted(value, f"{name}.") if isinstance(value, Mapping) else {name}
    return frozenset(out)


def material_keys(values: Mapping[str, Any]) -> frozenset[str]:
    """The dotted slicing keys a ``[material]`` table sets."""
    return frozenset(KEYS[k] for k in values if k in KEYS)


def describe(settings: SliceSettings) -> str:
    """The material in use, in one line."""
    return (f"material: E {settings.fea_youngs_modulus_mpa:g} MPa, Poisson's ratio "
            f"{settings.fea_poisson_ratio:g}, density {settings.filament_density:g} g/cm^3")


__all__ = ["KEYS", "describe", "file_settings", "material_keys", "material_settings"]
