"""Small printed coupons pulled along x: the roads resolved in the mesh, or homogenised per box.

A coupon is a flat bar of layers of straight roads, each layer at its own angle
(``+angle`` and ``-angle`` alternately), at a fill between solid tabs at both
ends, optionally inside a perimeter wall. It is analysed two ways on the same
solver: with boxes finer than a road (each box as stiff as the fraction the
roads fill, :func:`slicer.fea.printed.modulus_scale`: the roads themselves,
bonded where they touch) and with coarse boxes whose elasticity comes from
:mod:`slicer.fea.roadstiff`. Both report the modulus an extensometer over the
middle of the bar would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slicer.fea.hexmesh import hex_mesh
from slicer.fea.loadcase import LoadCase, parse_load_case
from slicer.fea.printed import Roads, fill_fractions, modulus_scale
from slicer.fea.roadstiff import box_elasticity
from slicer.fea.solve import analyse
from slicer.fea.voxel import VoxelGrid


@dataclass(frozen=True)
class Coupon:
    """A coupon ``length`` x ``width`` mm of ``layers`` layers of ``height`` mm, roads
    ``road`` mm wide at ``fill`` of each layer at +-``angle`` degrees to x (alternating),
    solid tabs of ``tab`` mm at each end, ``wall`` True for one perimeter road (the
    roads inside overlap it by ``overlap`` of a road's width, as the slicer's
    ``infill.overlap``)."""

    length: float = 16.0
    width: float = 6.0
    layers: int = 4
    height: float = 0.2
    road: float = 0.45
    fill: float = 0.4
    angle: float = 45.0
    tab: float = 3.0
    wall: bool = False
    overlap: float = 0.15

    @property
    def thickness(self) -> float:
        """The coupon's thickness, mm."""
        return self.layers * self.height


def _hatch(lo: np.ndarray, hi: np.ndarray, angle: float, spacing: float) -> np.ndarray:
    """Parallel lines at ``angle`` degrees, ``spacing`` mm apart, clipped to the box lo..hi
    (2,): segments (n, 2, 2) (Liang-Barsky, all lines at once)."""
    direction = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    normal = np.array([-direction[1], direction[0]])
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [lo[0], hi[1]], [hi[0], hi[1]]])
    reach = corners @ normal
    offsets = np.arange(np.floor(reach.min() / spacing), np.ceil(reach.max() / spacing) + 1)
    offsets = offsets * spacing + 0.5 * spacing
    origin = offsets[:, None] * normal[None, :]
    t0 = np.full(len(offsets), -1e9)
    t1 = np.full(len(offsets), 1e9)
    for axis in range(2):
        d = direction[axis]
        if abs(d) < 1e-12:
            outside = (origin[:, axis] < lo[axis]) | (origin[:, axis] > hi[axis])
            t1 = np.where(outside, -1e9, t1)
            continue
        a = (lo[axis] - origin[:, axis]) / d
        b = (hi[axis] - origin[:, axis]) / d
        t0 = np.maximum(t0, np.minimum(a, b))
        t1 = np.minimum(t1, np.maximum(a, b))
    keep = t1 - t0 > 1e-6
    start = origin[keep] + t0[keep, None] * direction
    end = origin[keep] + t1[keep, None] * direction
    return np.stack([start, end], axis=1)


def coupon_roads(coupon: Coupon) -> Roads:
    """The roads of ``coupon`` (model frame: x 0..length, y 0..width, z 0..thickness)."""
    c = coupon
    half = c.road / 2.0
    inner_lo = np.array([half, half]) + (c.road * (1.0 - c.overlap) if c.wall else 0.0)
    inner_hi = np.array([c.length, c.width]) - inner_lo
    parts, tops = [], []
    for layer in range(c.layers):
        angle = c.angle if layer % 2 == 0 else -c.angle
        segments = [
            _hatch(np.array([inner_lo[0], inner_lo[1]]), np.array([c.tab, inner_hi[1]]),
                   angle, c.road),
            _hatch(np.array([c.tab, inner_lo[1]]), np.array([c.length - c.tab, inner_hi[1]]),
                   angle, c.road / c.fill),
            _hatch(np.array([c.length - c.tab, inner_lo[1]]), np.array([inner_hi[0],
                   inner_hi[1]]), angle, c.road),
        ]
        if c.wall:
            a, b = half, np.array([c.length - half, c.width - half])
            ring = np.array([[a, a], [b[0], a], [b[0], b[1]], [a, b[1]], [a, a]])
            segments.append(np.stack([ring[:-1], ring[1:]], axis=1))
        layer_roads = np.concatenate(segments)
        parts.append(layer_roads)
        tops.append(np.full(len(layer_roads), (layer + 1) * c.height))
    ends = np.concatenate(parts)
    top = np.concatenate(tops)
    n = len(ends)
    return Roads(ends, top, np.full(n, c.height), np.full(n, c.road))


def _grid(coupon: Coupon, size: float, size_z: float) -> VoxelGrid:
    extent = np.array([coupon.length, coupon.width, coupon.thickness])
    shape = np.maximum(np.rint(extent / np.array([size, size, size_z])).astype(int), 1)
    return VoxelGrid(np.zeros(3), extent / shape, np.ones(tuple(shape), dtype=bool))


def coupon_case(coupon: Coupon, youngs: float, poisson: float, newtons: float = 100.0) -> LoadCase:
    """One end face held, ``newtons`` along +x spread over the other end face."""
    c = coupon
    return parse_load_case(
        f"[material]\nyoungs_modulus_mpa = {youngs!r}\npoisson_ratio = {poisson!r}\n"
        f"[[fixed]]\nbox = [[0, 0, 0], [0, {c.width!r}, {c.thickness!r}]]\n"
        f"[[force]]\nbox = [[{c.length!r}, 0, 0], [{c.length!r}, {c.width!r}, {c.thickness!r}]]\n"
        f"newtons = [{newtons!r}, 0, 0]\n", "coupon.load.toml")


def gage_modulus(points: np.ndarray, displacement: np.ndarray, coupon: Coupon,
                 newtons: float) -> float:
    """Nominal stress over the strain between the lattice planes nearest the middle
    third of the lattice's length (mean x displacement over each whole plane), MPa."""
    c = coupon
    span = (c.length - 2.0 * c.tab) / 3.0
    wanted = (c.tab + span, c.length - c.tab - span)
    planes = np.unique(np.round(points[:, 0], 9))
    ends = [float(planes[np.argmin(np.abs(planes - w))]) for w in wanted]
    mean = [float(displacement[np.abs(points[:, 0] - x) < 1e-6, 0].mean()) for x in ends]
    strain = (mean[1] - mean[0]) / (ends[1] - ends[0])
    return newtons / (c.width * c.thickness) / strain


def resolved_modulus(coupon: Coupon, youngs: float = 2200.0, poisson: float = 0.35,
                     size: float = 0.15) -> float:
    """The coupon's modulus with its roads resolved on boxes of ``size`` mm in x and y and
    half a layer in z (each box as stiff as the fraction the roads fill), MPa."""
    grid = _grid(coupon, size, coupon.height / 2.0)
    mesh = hex_mesh(grid)
    fractions = fill_fractions(coupon_roads(coupon), grid, np.zeros(3))
    case = coupon_case(coupon, youngs, poisson)
    solution = analyse(mesh, case, modulus_scale(fractions, mesh.cells))
    return gage_modulus(mesh.points, solution.displacement, coupon, 100.0)


def homogenised_modulus(coupon: Coupon, youngs: float = 2200.0, poisson: float = 0.35,
                        size: float = 0.5) -> float:
    """The coupon's modulus on boxes of about ``size`` mm whose elasticity comes from the
    roads' fill and direction (:func:`slicer.fea.roadstiff.box_elasticity`), MPa."""
    grid = _grid(coupon, size, size)
    mesh = hex_mesh(grid)
    elasticity = box_elasticity(coupon_roads(coupon), grid, np.zeros(3), poisson, mesh.cells)
    case = coupon_case(coupon, youngs, poisson)
    solution = analyse(mesh, case, elasticity=elasticity)
    return gage_modulus(mesh.points, solution.displacement, coupon, 100.0)


def fill_modulus(coupon: Coupon, youngs: float = 2200.0, poisson: float = 0.35,
                 size: float = 0.5) -> float:
    """The coupon's modulus with each box at ``E * fill`` whatever the roads' direction
    (the rule of mixtures the prediction used before), MPa."""
    grid = _grid(coupon, size, size)
    mesh = hex_mesh(grid)
    fractions = fill_fractions(coupon_roads(coupon), grid, np.zeros(3))
    case = coupon_case(coupon, youngs, poisson)
    solution = analyse(mesh, case, modulus_scale(fractions, mesh.cells))
    return gage_modulus(mesh.points, solution.displacement, coupon, 100.0)
