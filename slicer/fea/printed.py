"""A printed part rebuilt from its G-code: roads as material, gaps as void, on the voxel grid."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slicer.fea.gage import extensometer
from slicer.fea.voxel import VoxelGrid

PIXEL_MM = 0.05  # the finest raster roads are drawn on before they are averaged to boxes
VOID = 1e-3  # stiffness left in an empty box (as a fraction), so the solver stays defined


@dataclass(frozen=True)
class Roads:
    """Extruded segments of a program: ``ends`` (n, 2, 2) float64 mm on the bed,
    ``top`` (n,) float64 the layer's top z, ``height`` (n,) its thickness and
    ``width`` (n,) the road's width from the volume extruded along it, mm."""

    ends: np.ndarray
    top: np.ndarray
    height: np.ndarray
    width: np.ndarray


def read_roads(lines: Iterable[str], filament_diameter: float) -> Roads:
    """The roads a Marlin program deposits (G0/G1 X Y Z E, G90/G91, M82/M83, G92).

    A move that extrudes while going sideways is a road; its width is the
    volume extruded (E times the filament's cross-section) over its length and
    the layer's thickness (the rise from the previous layer's height).
    """
    area = math.pi * (filament_diameter / 2.0) ** 2
    x = y = z = e = 0.0
    absolute_xyz, absolute_e = True, False
    layer_z, below = 0.0, 0.0
    rows: list[tuple[float, float, float, float, float, float, float]] = []
    for raw in lines:
        code = raw.split(";", 1)[0].split()
        if not code:
            continue
        cmd = code[0].upper()
        if cmd in ("G90", "G91"):
            absolute_xyz = cmd == "G90"
            continue
        if cmd in ("M82", "M83"):
            absolute_e = cmd == "M82"
            continue
        words = {w[0].upper(): float(w[1:]) for w in code[1:] if len(w) > 1 and _number(w[1:])}
        if cmd == "G92":
            e = words.get("E", e)
            continue
        if cmd not in ("G0", "G1"):
            continue
        nx, ny, nz = x, y, z
        if "X" in words:
            nx = words["X"] if absolute_xyz else x + words["X"]
        if "Y" in words:
            ny = words["Y"] if absolute_xyz else y + words["Y"]
        if "Z" in words:
            nz = words["Z"] if absolute_xyz else z + words["Z"]
        de = 0.0
        if "E" in words:
            de = words["E"] - e if absolute_e else words["E"]
            e = words["E"] if absolute_e else e + words["E"]
        length = math.hypot(nx - x, ny - y)
        if de > 0 and length > 1e-9:
            if nz > layer_z + 1e-6:
                below, layer_z = layer_z, nz
            height = max(layer_z - below, 1e-3)
            rows.append((x, y, nx, ny, layer_z, height, de * area / (length * height)))
        x, y, z = nx, ny, nz
    table = np.array(rows, dtype=float).reshape(-1, 7)
    return Roads(table[:, :4].reshape(-1, 2, 2), table[:, 4], table[:, 5], table[:, 6])


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def fill_fractions(roads: Roads, grid: VoxelGrid, shift: np.ndarray) -> np.ndarray:
    """The fraction of each box of ``grid`` that the roads fill: (nx, ny, nz) float64 0..1.

    ``shift`` (3,) mm takes bed coordinates to the model frame of ``grid``. Each
    layer's roads are painted (round-ended, at their widths) on a raster of about
    :data:`PIXEL_MM` that divides the boxes exactly; overlapping roads count once.
    The raster is averaged over each box's footprint, then the layers over each
    box's height by how much of it they span.
    """
    nx, ny, nz = grid.solid.shape
    sub = np.maximum(np.ceil(grid.cell[:2] / PIXEL_MM).astype(int), 1)
    pixel = grid.cell[:2] / sub
    tops = np.unique(np.round(roads.top, 6))
    fractions = np.zeros((nx, ny, nz))
    bottoms = grid.origin[2] + grid.cell[2] * np.arange(nz)
    for top in tops:
        pick = np.abs(roads.top - top) < 1e-6
        height = float(np.median(roads.height[pick]))
        canvas = np.zeros((nx * sub[0], ny * sub[1]), dtype=bool)
        ends = roads.ends[pick] + shift[:2] - grid.origin[:2]
        scale = float(np.mean(pixel))  # pixels are square within a few per cent
        paint_roads(canvas, ends / pixel, roads.width[pick] / scale,
                    np.ones(int(pick.sum()), dtype=bool))
        covered = canvas.astype(float)  # (x pixels, y pixels)
        blocks = covered.reshape(nx, sub[0], ny, sub[1]).mean(axis=(1, 3))
        z0, z1 = top + shift[2] - height, top + shift[2]
        overlap = np.clip(np.minimum(z1, bottoms + grid.cell[2]) - np.maximum(z0, bottoms), 0,
                          None) / grid.cell[2]
        fractions += blocks[:, :, None] * overlap[None, None, :]
    return np.clip(fractions, 0.0, 1.0)


def paint_roads(canvas: np.ndarray, ends: np.ndarray, widths: np.ndarray,
                marks: np.ndarray) -> None:
    """Mark on ``canvas`` (x pixels, y pixels) every pixel whose centre lies within half a
    width of a road: ``ends`` (n, 2, 2) in pixels (pixel i spans i..i+1), ``widths``
    (n,) pixels, ``marks`` (n,) the value each road writes (a later road wins). Round
    ends, and the exact width at every angle (a drawing library's thick lines and
    polygons gain or lose up to a pixel's width depending on the angle)."""
    nx, ny = canvas.shape
    for (a, b), width, mark in zip(ends, widths, marks, strict=True):
        r = 0.5 * float(width)
        lo = np.floor(np.minimum(a, b) - r).astype(int)
        hi = np.ceil(np.maximum(a, b) + r).astype(int)
        x0, y0 = max(lo[0], 0), max(lo[1], 0)
        x1, y1 = min(hi[0], nx), min(hi[1], ny)
        if x0 >= x1 or y0 >= y1:
            continue
        px = np.arange(x0, x1) + 0.5 - a[0]
        py = np.arange(y0, y1) + 0.5 - a[1]
        d = b - a
        length2 = float(d @ d)
        t = np.zeros((len(px), len(py)))
        if length2 > 1e-18:
            t = np.clip((px[:, None] * d[0] + py[None, :] * d[1]) / length2, 0.0, 1.0)
        gap2 = (px[:, None] - t * d[0]) ** 2 + (py[None, :] - t * d[1]) ** 2
        window = canvas[x0:x1, y0:y1]
        window[gap2 <= r * r] = mark


def modulus_scale(fractions: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Each element's stiffness as a fraction of the solid's: its fill fraction (the
    rule of mixtures, blind to road direction), never under :data:`VOID`.
    ``cells`` (e, 3) int64 lattice indices -> (e,) float64."""
    scale: NDArray[np.float64] = np.maximum(fractions[tuple(cells.T)], VOID)
    return scale


def apparent_modulus(
    points: np.ndarray,
    displacement: np.ndarray,
    gage: tuple[float, float],
    band: tuple[float, float],
    newtons: float,
    area_mm2: float,
) -> float:
    """The modulus a tension test reports, MPa: nominal stress over gage strain.

    ``points`` (n, 3) and ``displacement`` (n, 3) mm of the mesh's nodes; the
    specimen is pulled along x; the extensometer spans x ``gage`` (the lattice
    planes nearest its ends) over y ``band``; ``newtons`` the pull and
    ``area_mm2`` the nominal cross-section of the gage.
    """
    weights, length = extensometer(points, gage, band)
    strain = float(np.sum(weights * displacement)) / length
    return newtons / area_mm2 / strain
