"""PNG thumbnails of a sliced model, embedded in G-code the way PrusaSlicer does (base64 blocks)."""

from __future__ import annotations

import base64
from typing import TYPE_CHECKING

import numpy as np
import shapely

from slicer.geom import sorted_unique
from slicer.raster import Canvas

if TYPE_CHECKING:
    from slicer.plan import SlicePlan

_LAYERS_DRAWN = 48  # layers stacked in the picture (evenly spaced)
_LINE = 78  # base64 characters per comment line (PrusaSlicer's)
_COS30, _SIN30 = 0.8660254037844386, 0.5


def parse_sizes(text: str) -> list[tuple[int, int]]:
    """``"32x32,220x124"`` -> [(32, 32), (220, 124)] (checked by the settings already)."""
    sizes = []
    for item in filter(None, text.split(",")):
        width, height = item.lower().split("x")
        sizes.append((int(width), int(height)))
    return sizes


def thumbnail_png(plan: SlicePlan, width: int, height: int) -> bytes:
    """An isometric picture of the model's layer outlines stacked, ``width`` x ``height`` px.

    Transparent background; faces shaded from dark (bottom) to light (top), each
    outline's border pixels darker. Drawn at twice the size and halved, so small
    thumbnails stay smooth; numpy and zlib only (no imaging library to import).
    """
    scale_up = 2
    w, h = width * scale_up, height * scale_up
    n = plan.layer_count
    picks = sorted_unique(np.linspace(0, n - 1, min(n, _LAYERS_DRAWN)).round().astype(int))
    xmin, ymin, xmax, ymax = plan.bounds
    ztop = plan.layer_z(n - 1) if n else 1.0
    corners = np.array([[x, y, z] for x in (xmin, xmax) for y in (ymin, ymax) for z in (0, ztop)])
    projected = _project(corners)
    lo, hi = projected.min(axis=0), projected.max(axis=0)
    span = np.maximum(hi - lo, 1e-6)
    fit = min((w * 0.92) / span[0], (h * 0.92) / span[1])
    offset = np.array([w, h]) / 2 - (lo + hi) / 2 * fit
    canvas = Canvas(w, h)
    groups, fills, edges = [], [], []
    for rank, i in enumerate(picks.tolist()):
        z = plan.layer_z(i)
        shade = 0.55 + 0.45 * (rank + 1) / len(picks)
        fills.append((int(235 * shade), int(120 * shade), int(30 * shade), 255))
        edges.append((int(120 * shade), int(55 * shade), int(10 * shade), 255))
        exteriors = shapely.get_exterior_ring(shapely.get_parts(plan.outline(i)))
        coords, ring_of = shapely.get_coordinates(exteriors, return_index=True)
        xyz = np.column_stack([coords, np.full(len(coords), z)])
        screen = _project(xyz) * fit + offset
        groups.append(np.split(screen, np.flatnonzero(np.diff(ring_of)) + 1) if len(coords)
                      else [])
    canvas.layers(groups, fills, edges)
    return canvas.halved().png()


def _project(xyz: np.ndarray) -> np.ndarray:
    """Isometric screen coordinates (y down) of points, (n, 3) mm -> (n, 2)."""
    sx = (xyz[:, 0] - xyz[:, 1]) * _COS30
    sy = -(xyz[:, 0] + xyz[:, 1]) * _SIN30 - xyz[:, 2]
    return np.column_stack([sx, sy])


def thumbnail_block(png: bytes, width: int, height: int) -> list[str]:
    """The comment lines of one thumbnail: ``; thumbnail begin WxH LEN``, base64, end."""
    text = base64.b64encode(png).decode("ascii")
    lines = [";", f"; thumbnail begin {width}x{height} {len(text)}"]
    lines += [f"; {text[k:k + _LINE]}" for k in range(0, len(text), _LINE)]
    lines += ["; thumbnail end", ";"]
    return lines


def thumbnail_lines(plan: SlicePlan, sizes: str) -> list[str]:
    """Every thumbnail block for the sizes of ``gcode.thumbnails`` (none for "")."""
    lines: list[str] = []
    for width, height in parse_sizes(sizes):
        lines += thumbnail_block(thumbnail_png(plan, width, height), width, height)
    return lines


def read_thumbnails(lines: list[str]) -> list[tuple[int, int, bytes]]:
    """The thumbnails embedded in G-code lines: (width, height, PNG bytes), in order.

    Raises ValueError when a block's length does not match its header.
    """
    found = []
    block: list[str] | None = None
    header = (0, 0, 0)
    for line in lines:
        if line.startswith("; thumbnail begin "):
            size, length = line.split()[3:5]
            width, height = map(int, size.split("x"))
            header = (width, height, int(length))
            block = []
        elif line.startswith("; thumbnail end") and block is not None:
            text = "".join(block)
            if len(text) != header[2]:
                raise ValueError(f"thumbnail {header[0]}x{header[1]}: {len(text)} characters,"
                                 f" the header says {header[2]}")
            found.append((header[0], header[1], base64.b64decode(text)))
            block = None
        elif block is not None:
            block.append(line[2:].strip())
    return found
