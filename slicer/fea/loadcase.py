"""Load cases (``NAME.load.toml``): fixed regions, forces, pressures and material, checked."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from slicer.errors import ModelError
from slicer.fea import LOAD_SUFFIX as LOAD_SUFFIX  # re-exported: imported from here too
from slicer.fea import load_path_for as load_path_for

ABS_YOUNGS_MPA = 2200.0
ABS_POISSON = 0.35
NORMAL_CONE_DEG = 30.0  # a face's outward normal must lie this close to a region's ``normal``

_TABLES = {
    "material": {"youngs_modulus_mpa", "poisson_ratio"},
    "fixed": {"box", "normal"},
    "force": {"box", "newtons", "normal"},
    "pressure": {"box", "mpa", "normal"},
    "test": {"gage_length_mm", "reads"},
}
READS = ("extensometer", "stiffness")  # what a test bench reads: [test] reads


class LoadCaseError(ModelError):
    """A load case that cannot be analysed; the message says which entry and why
    (a ModelError: the job cannot be sliced as asked)."""


@dataclass(frozen=True)
class Region:
    """Surface faces inside ``box`` ((2, 3) float64 mm, model frame) and, when ``normal``
    ((3,) unit vector) is set, facing within 30 degrees of it. ``label`` names the
    entry in messages, e.g. ``[[force]] 1``."""

    label: str
    box: np.ndarray
    normal: np.ndarray | None


@dataclass(frozen=True)
class Load:
    """A total force (``vector`` (3,) N) or a pressure (``mpa``, positive into the part)
    spread over a region's faces by area."""

    region: Region
    vector: np.ndarray | None = None
    mpa: float | None = None


@dataclass(frozen=True)
class LoadCase:
    """A whole load case: isotropic material, regions held fixed, and loads."""

    youngs_mpa: float
    poisson: float
    fixed: tuple[Region, ...]
    loads: tuple[Load, ...]
    source: str = "load case"
    gage_length_mm: float = 0.0  # [test] gage_length_mm; 0: the default (slicer.fea.gage)
    reads: str = ""  # [test] reads; "": the extensometer for a pull along x, else stiffness

    def key(self) -> str:
        """A stable digest of everything that changes the analysis (for caching)."""
        import hashlib

        digest = hashlib.sha256()
        digest.update(repr((self.youngs_mpa, self.poisson)).encode())
        for region in self.fixed:
            digest.update(_region_bytes(region))
        for load in self.loads:
            digest.update(_region_bytes(load.region))
            vector = load.vector if load.vector is not None else np.zeros(3)
            digest.update(np.asarray(vector, dtype="<f8").tobytes())
            digest.update(repr(load.mpa).encode())
        if self.gage_length_mm or self.reads:  # the optimum reads the named gage
            digest.update(repr((self.gage_length_mm, self.reads)).encode())
        return digest.hexdigest()


def _region_bytes(region: Region) -> bytes:
    normal = region.normal if region.normal is not None else np.zeros(3)
    return region.box.astype("<f8").tobytes() + np.asarray(normal, dtype="<f8").tobytes()


def read_load_case(
    path: str | os.PathLike[str], youngs: float = ABS_YOUNGS_MPA, poisson: float = ABS_POISSON
) -> LoadCase:
    """Parse and check the load case file at ``path`` (see :func:`parse_load_case`)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise LoadCaseError(f"{path.name}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise LoadCaseError(f"{path.name}: cannot read it: {exc}") from exc
    return parse_load_case(text, path.name, youngs, poisson)


def parse_load_case(
    text: str,
    source: str = "load case",
    youngs: float = ABS_YOUNGS_MPA,
    poisson: float = ABS_POISSON,
) -> LoadCase:
    """Parse the TOML ``text`` of a load case, refusing anything the contract does not allow.

    ``youngs`` (MPa) and ``poisson`` are the material when the case has no
    ``[material]`` (the slicing settings' ``fea.*``; ABS by default).
    Refused, each with its own reason prefixed by ``source``: invalid TOML,
    unknown tables and keys, a box that is not two finite corners in order, a
    zero or non-finite normal, force or pressure, a material out of range, no
    ``[[fixed]]`` region, no load at all. Geometry (a region that selects no
    face, motion left free) is checked against the mesh by the analysis.
    """
    import tomllib  # loaded when a load case is read, not by every slice

    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise LoadCaseError(f"{source}: not valid TOML: {exc}") from exc
    for key, value in data.items():
        if key not in _TABLES:
            raise LoadCaseError(
                f"{source}: unknown table or key {key!r} "
                "(use material, test, fixed, force, pressure)"
            )
        if key in ("material", "test") and not isinstance(value, dict):
            raise LoadCaseError(f"{source}: [{key}] must be a table")
        if key not in ("material", "test") and not (
            isinstance(value, list) and all(isinstance(v, dict) for v in value)
        ):
            raise LoadCaseError(f"{source}: {key} must be written as [[{key}]] tables")
    material = data.get("material", {})
    _known(material, "material", "[material]", source)
    youngs = _number(material.get("youngs_modulus_mpa", youngs),
                     "[material] youngs_modulus_mpa", source)
    poisson = _number(material.get("poisson_ratio", poisson),
                      "[material] poisson_ratio", source)
    if youngs <= 0:
        raise LoadCaseError(f"{source}: [material] youngs_modulus_mpa must be positive")
    if not -1.0 < poisson < 0.5:
        raise LoadCaseError(f"{source}: [material] poisson_ratio must lie between -1 and 0.5")
    fixed = tuple(
        _region(entry, "fixed", n, source) for n, entry in enumerate(data.get("fixed", []), 1)
    )
    if not fixed:
        raise LoadCaseError(
            f"{source}: nothing is fixed (no [[fixed]] region): the part is free to move "
            "along x, y and z and to turn about them"
        )
    loads: list[Load] = []
    for n, entry in enumerate(data.get("force", []), 1):
        region = _region(entry, "force", n, source)
        vector = _vector(entry.get("newtons"), f"{region.label} newtons", source)
        if not np.any(vector != 0):
            raise LoadCaseError(f"{source}: {region.label} newtons is zero: a load must push")
        loads.append(Load(region, vector=vector))
    for n, entry in enumerate(data.get("pressure", []), 1):
        region = _region(entry, "pressure", n, source)
        mpa = _number(entry.get("mpa"), f"{region.label} mpa", source)
        if mpa == 0:
            raise LoadCaseError(f"{source}: {region.label} mpa is zero: a load must push")
        loads.append(Load(region, mpa=mpa))
    if not loads:
        raise LoadCaseError(f"{source}: no load: give at least one [[force]] or [[pressure]]")
    test = data.get("test", {})
    _known(test, "test", "[test]", source)
    gage = 0.0
    if "gage_length_mm" in test:
        gage = _number(test["gage_length_mm"], "[test] gage_length_mm", source)
        if gage <= 0:
            raise LoadCaseError(f"{source}: [test] gage_length_mm must be positive")
    reads = test.get("reads", "")
    if "reads" in test and reads not in READS:
        raise LoadCaseError(f"{source}: [test] reads must be one of {', '.join(READS)}, "
                            f"got {reads!r}")
    return LoadCase(youngs, poisson, fixed, tuple(loads), source, gage, str(reads))


def _known(entry: dict[str, Any], table: str, label: str, source: str) -> None:
    unknown = sorted(set(entry) - _TABLES[table])
    if unknown:
        allowed = ", ".join(sorted(_TABLES[table]))
        raise LoadCaseError(f"{source}: {label}: unknown key {unknown[0]!r} (allowed: {allowed})")


def _number(value: Any, label: str, source: str) -> float:
    if value is None:
        raise LoadCaseError(f"{source}: {label} is missing")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise LoadCaseError(f"{source}: {label} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise LoadCaseError(f"{source}: {label} must be finite, got {value!r}")
    return float(value)


def _vector(value: Any, label: str, source: str) -> np.ndarray:
    if value is None:
        raise LoadCaseError(f"{source}: {label} is missing")
    if not isinstance(value, list) or len(value) != 3:
        raise LoadCaseError(f"{source}: {label} must be three numbers [x, y, z], got {value!r}")
    return np.array([_number(v, label, source) for v in value], dtype=float)


def _region(entry: dict[str, Any], table: str, n: int, source: str) -> Region:
    label = f"[[{table}]] {n}"
    _known(entry, table, label, source)
    box = entry.get("box")
    if (
        not isinstance(box, list)
        or len(box) != 2
        or not all(isinstance(corner, list) and len(corner) == 3 for corner in box)
    ):
        raise LoadCaseError(
            f"{source}: {label} box must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got {box!r}"
        )
    corners = np.array(
        [[_number(v, f"{label} box", source) for v in corner] for corner in box], dtype=float
    )
    if np.any(corners[0] > corners[1]):
        raise LoadCaseError(f"{source}: {label} box's first corner must be its least (min <= max)")
    normal = None
    if "normal" in entry:
        normal = _vector(entry["normal"], f"{label} normal", source)
        length = float(np.linalg.norm(normal))
        if length == 0:
            raise LoadCaseError(f"{source}: {label} normal is zero")
        normal = normal / length
    return Region(label, corners, normal)
