"""PNG thumbnails of a sliced model, embedded in G-code the way PrusaSlicer does (base64 blocks)."""

from __future__ import annotations

import base64
from typing import TYPE_CHECKING

import numpy as np
import shapely

from slicer.geometry.geom import sorted_unique
from slicer.geometry.raster import Canvas

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


class _Stack:
    """The stacked outlines of a thumbnail, projected once for every size: the exterior
    rings' points (m, 2) in unscaled screen units, each point's ring (m,) int64
    (ascending), each ring's layer rank (r,) int64, and the projected bounding box."""

    def __init__(self, plan: SlicePlan) -> None:
        n = plan.layer_count
        picks = sorted_unique(np.linspace(0, n - 1, min(n, _LAYERS_DRAWN)).round().astype(int))
        self.layers = len(picks)
        xmin, ymin, xmax, ymax = plan.bounds
        ztop = plan.layer_z(n - 1) if n else 1.0
        corners = np.array(
            [[x, y, z] for x in (xmin, xmax) for y in (ymin, ymax) for z in (0, ztop)])
        projected = _project(corners)
        self.lo, self.hi = projected.min(axis=0), projected.max(axis=0)
        outlines = np.array([plan.outline(i) for i in picks.tolist()], dtype=object)
        tops = np.array([plan.layer_z(i) for i in picks.tolist()])
        parts, rank = shapely.get_parts(outlines, return_index=True)
        coords, ring_of = shapely.get_coordinates(
            shapely.get_exterior_ring(parts), return_index=True)
        xyz = np.column_stack([coords, tops[rank[ring_of]]])
        self.points = _project(xyz)
        self.ring_of = ring_of
        self.rank = rank

    def screen(self, w: int, h: int) -> np.ndarray:
        """The points on a ``w`` x ``h`` canvas (the model fitted to 92 % of it), (m, 2)."""
        span = np.maximum(self.hi - self.lo, 1e-6)
        fit = min((w * 0.92) / span[0], (h * 0.92) / span[1])
        offset = np.array([w, h]) / 2 - (self.lo + self.hi) / 2 * fit
        screen: np.ndarray = self.points * fit + offset
        return screen


def thumbnail_png(
    plan: SlicePlan, width: int, height: int, stack: _Stack | None = None
) -> bytes:
    """An isometric picture of the model's layer outlines stacked, ``width`` x ``height`` px.

    Transparent background; faces shaded from dark (bottom) to light (top), each
    outline's border pixels darker. Drawn at twice the size and halved, so small
    thumbnails stay smooth; numpy and zlib only (no imaging library to import).
    ``stack``: the outlines already gathered (:class:`_Stack`), shared by every size.
    """
    scale_up = 2
    w, h = width * scale_up, height * scale_up
    stack = stack if stack is not None else _Stack(plan)
    fills, edges = [], []
    for rank in range(stack.layers):
        shade = 0.55 + 0.45 * (rank + 1) / stack.layers
        fills.append((int(235 * shade), int(120 * shade), int(30 * shade), 255))
        edges.append((int(120 * shade), int(55 * shade), int(10 * shade), 255))
    canvas = Canvas(w, h)
    canvas.packed_layers(stack.screen(w, h), stack.ring_of, stack.rank, fills, edges)
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
    wanted = parse_sizes(sizes)
    stack = _Stack(plan) if wanted else None
    for width, height in wanted:
        lines += thumbnail_block(thumbnail_png(plan, width, height, stack), width, height)
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
