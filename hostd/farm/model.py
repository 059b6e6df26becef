"""A submitted model's checks: an STL (binary or ASCII) within the size limit, and its footprint."""

from __future__ import annotations

import re

import numpy as np


class Refused(ValueError):
    """A submission the farm does not take; the message says why."""


_BINARY_HEADER = 84
_BINARY_FACET = 50
_ASCII_VERTEX = re.compile(
    rb"vertex\s+([-+0-9.eE]+)\s+([-+0-9.eE]+)\s+([-+0-9.eE]+)")


def footprint(name: str, data: bytes, max_bytes: int) -> tuple[float, float]:
    """The model's X and Y extent in mm; :class:`Refused` when ``data`` is not an STL of
    at least one triangle, or is larger than ``max_bytes``."""
    if len(data) > max_bytes:
        raise Refused(f"{name} is {len(data)} bytes, over the farm's limit of {max_bytes} bytes"
                      " (farm.max_bytes)")
    if not name.lower().endswith(".stl"):
        raise Refused(f"{name} is not an STL file (the farm takes .stl models)")
    if not data:
        raise Refused(f"{name} is empty (0 bytes)")
    points = _binary_points(data)
    if points is None:
        points = _ascii_points(data)
    if points is None or len(points) == 0:
        raise Refused(f"{name} is not an STL file: neither a binary STL (84-byte header, "
                      "50 bytes a triangle) nor an ASCII one (solid ... facet ... vertex)")
    if not np.isfinite(points).all():
        raise Refused(f"{name}: a vertex is not a finite number")
    extent = points.max(axis=0) - points.min(axis=0)
    return float(extent[0]), float(extent[1])


def _binary_points(data: bytes) -> np.ndarray | None:
    """The vertices of a binary STL whose length matches its triangle count, else None."""
    if len(data) < _BINARY_HEADER + _BINARY_FACET:
        return None
    count = int.from_bytes(data[80:84], "little")
    if count == 0 or len(data) != _BINARY_HEADER + _BINARY_FACET * count:
        return None
    record = np.dtype([("normal", "<f4", 3), ("points", "<f4", (3, 3)), ("attr", "<u2")])
    facets = np.frombuffer(data, dtype=record, count=count, offset=_BINARY_HEADER)
    return facets["points"].reshape(-1, 3).astype(np.float64)


def _ascii_points(data: bytes) -> np.ndarray | None:
    """The vertices of an ASCII STL (``solid`` ... ``facet`` ... ``vertex x y z``), else None."""
    if data.lstrip()[:5].lower() != b"solid" or b"facet" not in data:
        return None
    found = _ASCII_VERTEX.findall(data)
    if not found or len(found) % 3:
        return None
    try:
        return np.array(found, dtype=np.float64)
    except ValueError:
        return None
