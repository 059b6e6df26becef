"""The printer's motion settings as Marlin reports them (``M503``), read by the link (the
simulated printer's answer is :mod:`drivers.sim.report`).

Marlin answers ``M503`` with the commands that would set its current settings, each
after an ``echo:`` prefix (none with ``M503 S0``) and under a comment heading; the
ones about motion are ``M201`` (maximum acceleration per axis, mm/s²), ``M203``
(maximum feedrate per axis, mm/s), ``M204`` (accelerations: ``P`` printing, ``R``
retracts, ``T`` travel; before Marlin 1.1 ``S`` printing and travel with ``T`` for
retracts) and ``M205`` (``J`` junction deviation mm, or ``X Y Z E`` jerk mm/s).
Anything else (other settings, temperature reports, ``Unknown command``, Klipper's
``//`` lines) is ignored, and a field not reported stays unknown (None).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field

AXES = ("X", "Y", "Z", "E")

_ECHO = re.compile(r"^(?:\s*echo\s*:)+", re.IGNORECASE)
_COMMAND = re.compile(r"^\s*(M20[1345])(?![\d.])(.*)$", re.IGNORECASE)
_PARAM = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+))", re.IGNORECASE)


@dataclass(frozen=True)
class PrinterMotion:
    """What a printer reported of its motion settings; None (or an absent axis) where it
    said nothing. Accelerations mm/s², feedrates and jerk mm/s, junction deviation mm;
    per-axis values are keyed ``"X"``, ``"Y"``, ``"Z"``, ``"E"``."""

    max_acceleration: dict[str, float] = field(default_factory=dict)
    max_feedrate: dict[str, float] = field(default_factory=dict)
    print_acceleration: float | None = None
    retract_acceleration: float | None = None
    travel_acceleration: float | None = None
    junction_deviation: float | None = None
    jerk: dict[str, float] = field(default_factory=dict)

    @property
    def reported(self) -> bool:
        """Whether the printer reported anything at all."""
        return bool(self.max_acceleration or self.max_feedrate or self.jerk) or any(
            v is not None for v in (self.print_acceleration, self.retract_acceleration,
                                    self.travel_acceleration, self.junction_deviation))

    def _xy_limited(self, value: float | None) -> float | None:
        """``value`` capped by the X and Y maximum accelerations (either may be alone)."""
        caps = [self.max_acceleration[a] for a in "XY" if a in self.max_acceleration]
        if value is None:
            return min(caps) if caps else None
        return min([value, *caps])

    def printing_acceleration(self) -> float | None:
        """The acceleration of a printing move in the XY plane, mm/s²: ``M204 P`` capped by
        ``M201 X`` and ``Y`` (what Marlin's planner does for a move along an axis)."""
        return self._xy_limited(self.print_acceleration)

    def travelling_acceleration(self) -> float | None:
        """The acceleration of a travel in the XY plane, mm/s²: ``M204 T`` (else ``P``)
        capped by ``M201 X`` and ``Y``."""
        travel = self.travel_acceleration
        return self._xy_limited(travel if travel is not None else self.print_acceleration)

    def describe(self) -> str:
        """One line for the log: every value reported."""
        parts = []
        if self.print_acceleration is not None:
            parts.append(f"print acceleration {self.print_acceleration:g} mm/s²")
        if self.travel_acceleration is not None:
            parts.append(f"travel acceleration {self.travel_acceleration:g}")
        if self.retract_acceleration is not None:
            parts.append(f"retract acceleration {self.retract_acceleration:g}")
        if self.max_acceleration:
            parts.append("max acceleration " + _axes(self.max_acceleration))
        if self.max_feedrate:
            parts.append("max feedrate " + _axes(self.max_feedrate))
        if self.junction_deviation is not None:
            parts.append(f"junction deviation {self.junction_deviation:g} mm")
        if self.jerk:
            parts.append("jerk " + _axes(self.jerk))
        return "; ".join(parts) if parts else "nothing reported"


def _axes(values: dict[str, float]) -> str:
    return " ".join(f"{axis}{values[axis]:g}" for axis in AXES if axis in values)


def parse_motion_report(lines: Iterable[str]) -> PrinterMotion:
    """The motion settings in the lines a printer sent in answer to ``M503`` (any order,
    with or without ``echo:``, comments after ``;`` dropped); never raises. A setting
    reported twice keeps its last value; non-finite or negative numbers are ignored."""
    max_accel: dict[str, float] = {}
    max_feed: dict[str, float] = {}
    jerk: dict[str, float] = {}
    found: dict[str, float] = {}
    for raw in lines:
        text = _ECHO.sub("", raw.split(";", 1)[0]).strip()
        match = _COMMAND.match(text)
        if match is None:
            continue
        code = match.group(1).upper()
        params: dict[str, float] = {}
        for letter, number in _PARAM.findall(match.group(2)):
            value = float(number)
            if 0.0 <= value < 1e9:
                params[letter.upper()] = value
        if code in ("M201", "M203") and params.get("T", 0.0) != 0.0:
            params.pop("E", None)  # another extruder's E (M201 T1 E...): T0's is kept
        if code == "M201":
            max_accel.update({a: params[a] for a in AXES if a in params})
        elif code == "M203":
            max_feed.update({a: params[a] for a in AXES if a in params})
        elif code == "M204":
            _accelerations(params, found)
        elif "J" in params:  # M205 with junction deviation
            found["junction"] = params["J"]
        else:  # M205 with classic jerk
            jerk.update({a: params[a] for a in AXES if a in params})
    return PrinterMotion(
        max_accel, max_feed, found.get("print"), found.get("retract"), found.get("travel"),
        found.get("junction"), jerk)


def _accelerations(params: dict[str, float], found: dict[str, float]) -> None:
    """``M204``'s fields into ``found`` (print, retract, travel)."""
    if "P" in params or "R" in params:  # Marlin 1.1 and later: P R T
        for letter, name in (("P", "print"), ("R", "retract"), ("T", "travel")):
            if letter in params:
                found[name] = params[letter]
    elif "S" in params:  # the older form: S printing and travel, T retracts
        found["print"] = found["travel"] = params["S"]
        if "T" in params:
            found["retract"] = params["T"]
    elif "T" in params:
        found["travel"] = params["T"]
