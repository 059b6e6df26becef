"""Support generation: support regions from layer outlines, and support toolpaths per layer."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import shapely

from slicer.fields.base import LayerContext
from slicer.fields.eggcrate import EggcrateField
from slicer.fields.paths import as_multiline, clip, empty_paths, linestring_parts
from slicer.geometry import geom
from slicer.settings import SliceSettings

MIN_WIDTH_LINES = 4.0  # narrowest support region kept, in line widths
INTERFACE_LAYERS = 2  # layers of denser lines right under the part
SUPPORT_PERIOD = 4.0  # support eggcrate period, in infill spacings
INTERFACE_SPACING = 2.0  # interface line spacing, in line widths: sparse so it breaks away


def support_regions(
    outlines: Sequence[shapely.Geometry], settings: SliceSettings, layer_height: float
) -> list[shapely.Geometry]:
    """Support region of every layer, from the layer outlines (whole-model pass).

    ``outlines[i]`` is layer ``i``'s solid region (polygons with holes, mm, bed
    coordinates), bottom layer first. Returns one (Multi)Polygon per layer,
    possibly empty: the part of the layers above that layer ``i`` does not cover,
    restricted to real overhangs (an area needs support only where a layer
    overhangs the one below it by more than ``layer_height * tan(support.angle)``),
    minus the part dilated by ``support.clearance``. Support stops
    ``ceil(support.clearance / layer_height)`` layers below the surface it holds
    up, and rests on the bed or on the part below. Regions narrower than
    ``MIN_WIDTH_LINES`` line widths are dropped: such a column cannot stand, and
    a gap that narrow bridges (an engraved letter, a slot).
    """
    count = len(outlines)
    if count == 0:
        return []
    solid = np.array([g if g is not None else shapely.Polygon() for g in outlines], dtype=object)
    empty = shapely.Polygon()
    slope = math.tan(math.radians(settings.support_angle))
    if settings.support_angle >= 89.999 or count < 2:
        return [shapely.Polygon() for _ in range(count)]
    reach = shapely.buffer(solid[:-1], layer_height * slope)
    bare = geom.difference(solid[1:], reach)
    # widen each overhang by the self-supported reach, so the thin bands of a steady
    # slope join into one area instead of slivers narrower than a line
    bare = geom.intersection(shapely.buffer(bare, layer_height * slope), solid[1:])
    overhang = np.concatenate(([empty], bare))
    gap = _gap_layers(settings, layer_height)
    regions = np.empty(count, dtype=object)
    carried = empty
    for i in range(count - 1, -1, -1):
        above = i + 1 + gap
        if above < count and not overhang[above].is_empty:
            carried = geom.union(carried, overhang[above])
        if not carried.is_empty:
            carried = geom.difference(carried, solid[i])
        regions[i] = carried
    width = settings.line_width
    regions = geom.difference(regions, shapely.buffer(solid, settings.support_clearance))
    narrow = 0.5 * MIN_WIDTH_LINES * width
    opened = shapely.buffer(shapely.buffer(regions, -narrow), narrow)
    regions = geom.intersection(opened, regions)  # arcs are polygons: never grow
    # a fresh empty per layer: no object shared by the layers (threads prepare them)
    return [shapely.Polygon() if g is None or g.is_empty else g for g in regions]


def support_interfaces(
    outlines: Sequence[shapely.Geometry],
    regions: Sequence[shapely.Geometry],
    settings: SliceSettings,
    layer_height: float,
) -> list[shapely.Geometry]:
    """The part of each support region just under the part (the interface layers).

    ``regions`` is what :func:`support_regions` returned for the same outlines.
    Returns one (Multi)Polygon per layer, a subset of ``regions[i]``: the area
    under the part within ``INTERFACE_LAYERS`` layers above the z gap.
    """
    count = len(regions)
    empty = shapely.Polygon()
    gap = _gap_layers(settings, layer_height)
    result: list[shapely.Geometry] = []
    for i in range(count):
        if regions[i] is None or regions[i].is_empty:
            result.append(shapely.Polygon())
            continue
        window = [g for g in outlines[i + 1 : i + 2 + gap + INTERFACE_LAYERS] if g is not None]
        roof = shapely.union_all(window) if window else empty
        result.append(geom.intersection(regions[i], roof))
    return result


def support_paths(
    region: shapely.Geometry,
    part_outline: shapely.Geometry,
    ctx: LayerContext,
    interface: shapely.Geometry | None = None,
) -> dict[str, shapely.Geometry]:
    """Support toolpaths of one layer.

    ``region`` is this layer's support region (from :func:`support_regions`),
    ``part_outline`` the layer's solid region, ``interface`` optionally the part
    of ``region`` directly under the part (from :func:`support_interfaces`).
    Returns ``{"wall": ..., "infill": ..., "interface": ...}``, each a
    (Multi)LineString in mm, possibly empty: one wall inside the region, eggcrate
    infill at ``support.density`` inside the wall, and sparse parallel lines on
    the interface.
    """
    settings = ctx.settings
    width = settings.line_width
    nothing = {"wall": empty_paths(), "infill": empty_paths(), "interface": empty_paths()}
    if region is None or region.is_empty:
        return nothing
    wall_rings = linestring_parts(shapely.boundary(shapely.buffer(region, -0.5 * width)))
    wall = as_multiline(wall_rings[shapely.length(wall_rings) >= 2.0 * width])
    inside = shapely.buffer(region, -width * (1.0 - settings.infill_overlap))
    roof = shapely.Polygon() if interface is None else geom.intersection(inside, interface)
    body = geom.difference(inside, roof) if not shapely.is_empty(roof) else inside
    infill = empty_paths()
    if not shapely.is_empty(body):
        spacing = width / settings.support_density
        infill = _support_field(settings, spacing).paths(body, ctx, spacing)
    lines = empty_paths()
    if not shapely.is_empty(roof):
        angle = settings.infill_angle + (90.0 if ctx.index % 2 else 0.0)
        lines = as_multiline(hatch(roof, INTERFACE_SPACING * width, angle))
    return {"wall": wall, "infill": infill, "interface": lines}


def hatch(region: shapely.Geometry, spacing: float, angle_deg: float) -> np.ndarray:
    """Parallel lines ``spacing`` mm apart at ``angle_deg``, clipped to ``region``:
    an array of LineStrings."""
    xmin, ymin, xmax, ymax = region.bounds
    cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
    half = 0.5 * math.hypot(xmax - xmin, ymax - ymin) + spacing
    offsets = np.arange(-half, half + spacing, spacing)
    t = math.radians(angle_deg)
    ux, uy = math.cos(t), math.sin(t)
    nx, ny = -uy, ux
    starts = np.column_stack((cx + offsets * nx - half * ux, cy + offsets * ny - half * uy))
    ends = np.column_stack((cx + offsets * nx + half * ux, cy + offsets * ny + half * uy))
    lines = shapely.linestrings(np.stack((starts, ends), axis=1))
    return clip(lines, region)


@functools.lru_cache(maxsize=8)
def _support_field(settings: SliceSettings, spacing: float) -> EggcrateField:
    """The support's eggcrate, one per (frozen) settings so the level step it fits once
    serves every layer. Its period is ``SUPPORT_PERIOD`` spacings at 45 degrees, so each
    cell holds a lattice line and about one ring whatever the density (the paper's
    dragon: levels -0.5, 0, 0.5 of a unit eggcrate)."""
    scale = min(max(SUPPORT_PERIOD * spacing, 0.5), 200.0)
    return EggcrateField(replace(settings, infill_scale=scale, infill_angle=45.0))


def _gap_layers(settings: SliceSettings, layer_height: float) -> int:
    """Layers left empty between the support's top and the part it holds up."""
    return math.ceil(settings.support_clearance / layer_height - 1e-9)
