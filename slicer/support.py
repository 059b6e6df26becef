"""Support generation: support regions from layer outlines, and support toolpaths per layer."""

from __future__ import annotations

from collections.abc import Sequence

import shapely

from slicer.fields.base import LayerContext
from slicer.settings import SliceSettings


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
    up, and rests on the bed or on the part below.
    """
    raise NotImplementedError


def support_interfaces(
    outlines: Sequence[shapely.Geometry],
    regions: Sequence[shapely.Geometry],
    settings: SliceSettings,
    layer_height: float,
) -> list[shapely.Geometry]:
    """The part of each support region just under the part (the interface layers).

    ``regions`` is what :func:`support_regions` returned for the same outlines.
    Returns one (Multi)Polygon per layer, a subset of ``regions[i]``.
    """
    raise NotImplementedError


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
    raise NotImplementedError
