"""Slicing settings: one frozen, validated object built from flat TOML-style keys."""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

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


class SettingsError(ValueError):
    """A slicing setting is unknown or out of range; the message names the key."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}")
        self.key = key
        self.reason = reason


@dataclass(frozen=True)
class _Spec:
    """How one flat key is checked: its type and allowed range or choices."""

    kind: type
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    length: int | None = None


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
                raise SettingsError(key, "unknown slicing setting")
            changes[key.replace(".", "_")] = _check(key, raw, spec)
        merged = dataclasses.replace(base or cls(), **changes)
        if merged.first_layer_height <= 0:
            raise SettingsError("first_layer_height", "must be positive")
        if not _THUMBNAILS.fullmatch(merged.gcode_thumbnails):
            raise SettingsError("gcode.thumbnails", f"{merged.gcode_thumbnails!r}: expected sizes"
                                " such as \"32x32,220x124\" (1..1024 px each), or \"\" for none")
        return merged

    def to_mapping(self) -> dict[str, Any]:
        """Flat dotted keys and values, the inverse of :meth:`from_mapping`."""
        return {key: getattr(self, key.replace(".", "_")) for key in _SPECS}

    @property
    def filament_area(self) -> float:
        """Cross-section of the filament, mm^2."""
        return 3.141592653589793 * (self.filament_diameter / 2.0) ** 2


def parse_assignment(text: str) -> tuple[str, Any]:
    """Parse ``KEY=VALUE`` from the command line into a key and a TOML-typed value."""
    import tomllib

    if "=" not in text:
        raise SettingsError(text, "expected KEY=VALUE")
    key, _, raw = text.partition("=")
    key = key.strip()
    raw = raw.strip()
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def _flatten(values: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def _check(key: str, raw: Any, spec: _Spec) -> Any:
    if spec.kind is bool:
        if not isinstance(raw, bool):
            raise SettingsError(key, f"expected true or false, got {raw!r}")
        return raw
    if spec.kind is str:
        if not isinstance(raw, str):
            raise SettingsError(key, f"expected a string, got {raw!r}")
        if spec.choices is not None and raw not in spec.choices:
            raise SettingsError(key, f"{raw!r} is not one of {', '.join(spec.choices)}")
        return raw
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise SettingsError(key, f"expected a number, got {raw!r}")
    if spec.kind is int and (isinstance(raw, float) and not raw.is_integer()):
        raise SettingsError(key, f"expected a whole number, got {raw!r}")
    value = spec.kind(raw)
    if value != value or value in (float("inf"), float("-inf")):
        raise SettingsError(key, "must be finite")
    if spec.low is not None and value < spec.low:
        raise SettingsError(key, f"{raw!r} is below the minimum {spec.low:g}")
    if spec.high is not None and value > spec.high:
        raise SettingsError(key, f"{raw!r} is above the maximum {spec.high:g}")
    return value


_SPECS: dict[str, _Spec] = {
    "layer_height": _Spec(float, 0.04, 1.0),
    "first_layer_height": _Spec(float, 0.04, 1.0),
    "line_width": _Spec(float, 0.1, 2.0),
    "perimeters": _Spec(int, 0, 20),
    "top_layers": _Spec(int, 0, 50),
    "bottom_layers": _Spec(int, 0, 50),
    "wall_order": _Spec(str, choices=WALL_ORDERS),
    "infill.field": _Spec(str, choices=INFILL_FIELDS),
    "infill.density": _Spec(float, 0.0, 1.0),
    "infill.angle": _Spec(float, -360.0, 360.0),
    "infill.overlap": _Spec(float, 0.0, 0.5),
    "infill.seed": _Spec(int, 0, 2**31 - 1),
    "infill.file": _Spec(str),
    "infill.expression": _Spec(str),
    "infill.scale": _Spec(float, 0.5, 200.0),
    "infill.solid_below_area": _Spec(float, 0.0, 10000.0),
    "infill.stress": _Spec(str, choices=STRESS_VARIANTS),
    "infill.load": _Spec(str),
    "infill.match_mass_of": _Spec(str, choices=MASS_MATCHES),
    "infill.target_mass_g": _Spec(float, 0.0, 100000.0),
    "fea.mesh_size": _Spec(float, 0.0, 50.0),
    "fea.youngs_modulus_mpa": _Spec(float, 1.0, 1e6),
    "fea.poisson_ratio": _Spec(float, 0.0, 0.49),
    "support.enabled": _Spec(bool),
    "support.angle": _Spec(float, 0.0, 90.0),
    "support.clearance": _Spec(float, 0.0, 5.0),
    "support.density": _Spec(float, 0.02, 1.0),
    "nozzle_temp": _Spec(float, 0.0, 350.0),
    "bed_temp": _Spec(float, 0.0, 150.0),
    "filament_diameter": _Spec(float, 1.0, 3.5),
    "filament_density": _Spec(float, 0.5, 3.0),
    "print_speed": _Spec(float, 1.0, 1000.0),
    "wall_speed": _Spec(float, 1.0, 1000.0),
    "first_layer_speed": _Spec(float, 1.0, 1000.0),
    "travel_speed": _Spec(float, 1.0, 1000.0),
    "retract_length": _Spec(float, 0.0, 20.0),
    "retract_speed": _Spec(float, 1.0, 200.0),
    "acceleration": _Spec(float, 10.0, 50000.0),
    "fan_speed": _Spec(float, 0.0, 1.0),
    "fan_first_layer": _Spec(int, 0, 1000),
    "skip_heating": _Spec(bool),
    "resolution": _Spec(float, 0.0, 1.0),
    "infill.resolution": _Spec(float, 0.0, 1.0),
    "gcode.arcs": _Spec(str, choices=ARC_MODES),
    "gcode.baud": _Spec(int, 0, 10_000_000),
    "gcode.coarse_resolution": _Spec(float, 0.0, 1.0),
    "gcode.planner_blocks": _Spec(int, 1, 256),
    "gcode.thumbnails": _Spec(str),
    "gcode.labels": _Spec(bool),
}
_SIZE = r"(?:[1-9]\d{0,2}|10[01]\d|102[0-4])"
_THUMBNAILS = re.compile(rf"(?:{_SIZE}x{_SIZE}(?:,{_SIZE}x{_SIZE})*)?")

SETTING_KEYS: tuple[str, ...] = tuple(_SPECS)


def setting_range(key: str) -> tuple[float | None, float | None]:
    """The lowest and highest value the flat setting ``key`` accepts (None: unbounded)."""
    spec = _SPECS[key]
    return spec.low, spec.high

__all__ = [
    "ARC_MODES",
    "INFILL_FIELDS",
    "SETTING_KEYS",
    "SettingsError",
    "SliceSettings",
    "parse_assignment",
    "setting_range",
]
