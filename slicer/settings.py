"""Slicing settings: one frozen, validated object built from flat TOML-style keys."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from slicer.options import Choice, Field, Flag, Number, SettingError, Text, Whole, parse_assignment

INFILL_FIELDS = (
    "linear",
    "wave",
    "eggcrate",
    "concentric",
    "random",
    "poisson",
    "stress",
    "expression",
)
WALL_ORDERS = ("outer_first", "inner_first")
# Eq. 14 with sigma(x, y, z), sigma along the long axis, or an optimised density in its place
STRESS_VARIANTS = ("A", "B", "optimal")
MASS_MATCHES = ("", "linear")
ARC_MODES = ("auto", "on", "off")


# the one settings error (``slicer.options``), by the name the slicer has always used
SettingsError = SettingError


@dataclass(frozen=True)
class SliceSettings:
    """Every setting the slicer reads. Lengths in mm, speeds in mm/s, temperatures in C.

    Keys use the flat dotted names of the configuration (`infill.density`); build
    one with :meth:`from_mapping`, which validates every key and value.
    """

    layer_height: float = 0.2
    first_layer_height: float = 0.2
    line_width: float = 0.45
    perimeters: int = 2
    top_layers: int = 4
    bottom_layers: int = 4
    wall_order: str = "outer_first"
    infill_field: str = "linear"
    infill_density: float = 0.2
    infill_angle: float = 45.0
    infill_overlap: float = 0.15
    infill_seed: int = 0
    infill_file: str = ""
    infill_expression: str = ""
    infill_scale: float = 10.0
    infill_solid_below_area: float = 70.0
    infill_stress: str = "A"
    infill_load: str = ""
    infill_match_mass_of: str = ""
    infill_target_mass_g: float = 0.0
    fea_mesh_size: float = 0.0
    fea_youngs_modulus_mpa: float = 2200.0
    fea_poisson_ratio: float = 0.35
    support_enabled: bool = False
    support_angle: float = 50.0
    support_clearance: float = 0.2
    support_density: float = 0.15
    nozzle_temp: float = 210.0
    bed_temp: float = 60.0
    filament_diameter: float = 1.75
    filament_density: float = 1.24
    print_speed: float = 50.0
    wall_speed: float = 40.0
    first_layer_speed: float = 20.0
    travel_speed: float = 150.0
    retract_length: float = 1.0
    retract_speed: float = 35.0
    acceleration: float = 1000.0
    fan_speed: float = 1.0
    fan_first_layer: int = 1
    skip_heating: bool = False
    resolution: float = 0.025
    infill_resolution: float = 0.1
    gcode_arcs: str = "auto"
    gcode_baud: int = 0
    gcode_coarse_resolution: float = 0.05
    gcode_planner_blocks: int = 16
    gcode_thumbnails: str = "32x32,220x124"
    gcode_labels: bool = True

    @classmethod
    def from_mapping(
        cls, values: Mapping[str, Any], base: SliceSettings | None = None
    ) -> SliceSettings:
        """Return settings from flat or nested keys, refusing unknown keys and bad values.

        ``values`` may be ``{"infill.density": 0.3}`` or ``{"infill": {"density": 0.3}}``.
        ``base`` supplies the values not given (defaults when omitted).
        """
        flat = _flatten(values)
        changes: dict[str, Any] = {}
        for key, raw in flat.items():
            spec = _SPECS.get(key)
            if spec is None:
                raise SettingError(key, "unknown slicing setting")
            changes[key.replace(".", "_")] = spec.check(key, raw)
        merged = dataclasses.replace(base or cls(), **changes)
        if merged.first_layer_height <= 0:
            raise SettingError("first_layer_height", "must be positive")
        if not _THUMBNAILS.fullmatch(merged.gcode_thumbnails):
            raise SettingError("gcode.thumbnails", f"{merged.gcode_thumbnails!r}: expected sizes"
                                " such as \"32x32,220x124\" (1..1024 px each), or \"\" for none")
        return merged

    def to_mapping(self) -> dict[str, Any]:
        """Flat dotted keys and values, the inverse of :meth:`from_mapping`."""
        return {key: getattr(self, key.replace(".", "_")) for key in _SPECS}

    @property
    def filament_area(self) -> float:
        """Cross-section of the filament, mm^2."""
        return 3.141592653589793 * (self.filament_diameter / 2.0) ** 2


def _flatten(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat




def _whole(low: int, high: int) -> Whole:
    """A whole-number setting within ``low..high``; ``3.0`` in a file is taken as 3."""
    return Whole(low, high, whole_floats=True)


_SPECS: dict[str, Field[Any]] = {
    "layer_height": Number(0.04, 1.0),
    "first_layer_height": Number(0.04, 1.0),
    "line_width": Number(0.1, 2.0),
    "perimeters": _whole(0, 20),
    "top_layers": _whole(0, 50),
    "bottom_layers": _whole(0, 50),
    "wall_order": Choice(WALL_ORDERS),
    "infill.field": Choice(INFILL_FIELDS),
    "infill.density": Number(0.0, 1.0),
    "infill.angle": Number(-360.0, 360.0),
    "infill.overlap": Number(0.0, 0.5),
    "infill.seed": _whole(0, 2**31 - 1),
    "infill.file": Text(),
    "infill.expression": Text(),
    "infill.scale": Number(0.5, 200.0),
    "infill.solid_below_area": Number(0.0, 10000.0),
    "infill.stress": Choice(STRESS_VARIANTS),
    "infill.load": Text(),
    "infill.match_mass_of": Choice(MASS_MATCHES),
    "infill.target_mass_g": Number(0.0, 100000.0),
    "fea.mesh_size": Number(0.0, 50.0),
    "fea.youngs_modulus_mpa": Number(1.0, 1e6),
    "fea.poisson_ratio": Number(0.0, 0.49),
    "support.enabled": Flag(),
    "support.angle": Number(0.0, 90.0),
    "support.clearance": Number(0.0, 5.0),
    "support.density": Number(0.02, 1.0),
    "nozzle_temp": Number(0.0, 350.0),
    "bed_temp": Number(0.0, 150.0),
    "filament_diameter": Number(1.0, 3.5),
    "filament_density": Number(0.5, 3.0),
    "print_speed": Number(1.0, 1000.0),
    "wall_speed": Number(1.0, 1000.0),
    "first_layer_speed": Number(1.0, 1000.0),
    "travel_speed": Number(1.0, 1000.0),
    "retract_length": Number(0.0, 20.0),
    "retract_speed": Number(1.0, 200.0),
    "acceleration": Number(10.0, 50000.0),
    "fan_speed": Number(0.0, 1.0),
    "fan_first_layer": _whole(0, 1000),
    "skip_heating": Flag(),
    "resolution": Number(0.0, 1.0),
    "infill.resolution": Number(0.0, 1.0),
    "gcode.arcs": Choice(ARC_MODES),
    "gcode.baud": _whole(0, 10_000_000),
    "gcode.coarse_resolution": Number(0.0, 1.0),
    "gcode.planner_blocks": _whole(1, 256),
    "gcode.thumbnails": Text(),
    "gcode.labels": Flag(),
}
_SIZE = r"(?:[1-9]\d{0,2}|10[01]\d|102[0-4])"
_THUMBNAILS = re.compile(rf"(?:{_SIZE}x{_SIZE}(?:,{_SIZE}x{_SIZE})*)?")

SETTING_KEYS: tuple[str, ...] = tuple(_SPECS)


def setting_range(key: str) -> tuple[float | None, float | None]:
    """The lowest and highest value the flat setting ``key`` accepts (None: unbounded)."""
    spec = _SPECS[key]
    if isinstance(spec, Number | Whole):
        return spec.low, spec.high
    return None, None

__all__ = [
    "ARC_MODES",
    "INFILL_FIELDS",
    "SETTING_KEYS",
    "SettingError",
    "SettingsError",
    "SliceSettings",
    "parse_assignment",
    "setting_range",
]
