"""What a farm job needs (material, nozzle, bed), what a printer declares, and why a job waits."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any


class NeedsError(ValueError):
    """A ``--needs`` text that cannot be read; the message says which part."""


@dataclass(frozen=True)
class Needs:
    """A job's needs: a loaded material, a nozzle diameter (mm), a bed at least X x Y mm."""

    material: str | None = None
    nozzle_mm: float | None = None
    bed: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON form (absent needs left out)."""
        out: dict[str, Any] = {}
        if self.material is not None:
            out["material"] = self.material
        if self.nozzle_mm is not None:
            out["nozzle"] = self.nozzle_mm
        if self.bed is not None:
            out["bed"] = [self.bed[0], self.bed[1]]
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Needs:
        """The inverse of :meth:`to_dict`."""
        bed = data.get("bed")
        nozzle = data.get("nozzle")
        return cls(
            material=data.get("material"),
            nozzle_mm=float(nozzle) if nozzle is not None else None,
            bed=(float(bed[0]), float(bed[1])) if bed is not None else None,
        )

    def at_least_bed(self, x: float, y: float) -> Needs:
        """These needs with the bed raised to hold an X x Y footprint."""
        if self.bed is None:
            return Needs(self.material, self.nozzle_mm, (x, y))
        return Needs(self.material, self.nozzle_mm, (max(self.bed[0], x), max(self.bed[1], y)))


def parse_needs(text: str) -> Needs:
    """``material=PETG,nozzle=0.4,bed=220x220`` (any subset, any order) to :class:`Needs`."""
    material: str | None = None
    nozzle: float | None = None
    bed: tuple[float, float] | None = None
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        key, eq, value = part.partition("=")
        key, value = key.strip().lower(), value.strip()
        if not eq or not value:
            raise NeedsError(f"{part!r}: expected KEY=VALUE (material, nozzle, bed)")
        if key == "material":
            material = value
        elif key == "nozzle":
            nozzle = _positive(value, part)
        elif key == "bed":
            x, times, y = value.lower().partition("x")
            if not times:
                raise NeedsError(f"{part!r}: the bed is WIDTHxDEPTH in mm, e.g. bed=220x220")
            bed = (_positive(x, part), _positive(y, part))
        else:
            raise NeedsError(f"{part!r}: unknown need {key!r} (material, nozzle, bed)")
    return Needs(material, nozzle, bed)


def _positive(text: str, part: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise NeedsError(f"{part!r}: {text!r} is not a number") from None
    if not math.isfinite(value) or value <= 0:
        raise NeedsError(f"{part!r}: must be a positive number")
    return value


@dataclass(frozen=True)
class Station:
    """What a printer declares to the farm: id, loaded material, nozzle (mm), bed X x Y (mm),
    whether it is idle, and when it said so (Unix time)."""

    printer: str
    material: str
    nozzle_mm: float
    bed: tuple[float, float]
    idle: bool = True
    seen: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        data = asdict(self)
        data["bed"] = list(self.bed)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Station:
        """The inverse of :meth:`to_dict`."""
        bed = data["bed"]
        return cls(str(data["printer"]), str(data["material"]), float(data["nozzle_mm"]),
                   (float(bed[0]), float(bed[1])), bool(data.get("idle", True)),
                   float(data.get("seen", 0.0)))


# two nozzle diameters closer than this are the same nozzle (0.4 and 0.40000001)
_NOZZLE_TOLERANCE_MM = 0.005


def _has_material(needs: Needs, station: Station) -> bool:
    return needs.material is None or needs.material.casefold() == station.material.casefold()


def _has_nozzle(needs: Needs, station: Station) -> bool:
    return needs.nozzle_mm is None or abs(needs.nozzle_mm - station.nozzle_mm) <= \
        _NOZZLE_TOLERANCE_MM


def _has_bed(needs: Needs, station: Station) -> bool:
    if needs.bed is None:
        return True
    need_x, need_y = needs.bed
    x, y = station.bed
    # a footprint may be turned a quarter on the bed: X x Y fits a Y x X bed
    return (need_x <= x and need_y <= y) or (need_x <= y and need_y <= x)


def misfit(needs: Needs, station: Station) -> str | None:
    """Why ``station`` cannot take a job with ``needs`` (None: it fits)."""
    missing = []
    if not _has_material(needs, station):
        missing.append(f"{needs.material} (it has {station.material} loaded)")
    if not _has_nozzle(needs, station):
        missing.append(f"a {needs.nozzle_mm:g} mm nozzle (it has {station.nozzle_mm:g} mm)")
    if not _has_bed(needs, station):
        assert needs.bed is not None
        missing.append(f"a {needs.bed[0]:g}x{needs.bed[1]:g} mm bed "
                       f"(its bed is {station.bed[0]:g}x{station.bed[1]:g})")
    return f"needs {', '.join(missing)}" if missing else None


def why_waiting(needs: Needs, stations: list[Station]) -> str:
    """Why a waiting job is not taken, given the printers that declare themselves now."""
    if not stations:
        return "no printer is taking farm jobs"
    fitting = [s for s in stations if misfit(needs, s) is None]
    if fitting:
        names = ", ".join(sorted(s.printer for s in fitting))
        return f"waiting for a free printer that fits ({names})"
    parts = []
    if not any(_has_material(needs, s) for s in stations):
        parts.append(f"needs {needs.material}: no printer has it loaded")
    if not any(_has_nozzle(needs, s) for s in stations):
        parts.append(f"needs a {needs.nozzle_mm:g} mm nozzle: no printer has one")
    if not any(_has_bed(needs, s) for s in stations):
        assert needs.bed is not None
        parts.append(f"needs a {needs.bed[0]:g}x{needs.bed[1]:g} mm bed: no printer's is "
                     "that large")
    if parts:
        return "; ".join(parts)
    return f"needs {describe(needs)}: no printer has all of it together"


def describe(needs: Needs) -> str:
    """``PETG, a 0.6 mm nozzle, a 300x300 mm bed`` (``anything`` when it needs nothing)."""
    parts = []
    if needs.material is not None:
        parts.append(needs.material)
    if needs.nozzle_mm is not None:
        parts.append(f"a {needs.nozzle_mm:g} mm nozzle")
    if needs.bed is not None:
        parts.append(f"a {needs.bed[0]:g}x{needs.bed[1]:g} mm bed")
    return ", ".join(parts) or "anything"
