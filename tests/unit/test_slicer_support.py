"""Support: regions under overhangs only, clear of the part, with wall, infill and interface."""

from __future__ import annotations

from functools import reduce
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh

from slicer.fields.base import LayerContext
from slicer.paths.support import support_interfaces, support_paths, support_regions
from slicer.settings import SliceSettings

DATA = Path(__file__).resolve().parents[1] / "data"
H = 0.2


def outlines(mesh: trimesh.Trimesh, h: float = H) -> list[shapely.Geometry]:
    """Each layer's cross-section at mid-layer, as polygons (even-odd nesting)."""
    heights = np.arange(h / 2, mesh.bounds[1, 2], h)
    cuts, _, _ = trimesh.intersections.mesh_multiplane(mesh, [0, 0, 0], [0, 0, 1], heights)
    layers = []
    for segments in cuts:
        if len(segments) == 0:
            layers.append(shapely.Polygon())
            continue
        lines = shapely.linestrings(np.round(np.asarray(segments)[:, :, :2], 6))
        faces = shapely.get_parts(shapely.polygonize(lines))
        layers.append(reduce(shapely.symmetric_difference, faces, shapely.Polygon()))
    return layers


def box(extents: tuple[float, float, float], corner: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(np.asarray(corner) + np.asarray(extents) / 2)
    return mesh


@pytest.fixture(scope="module")
def tee() -> list[shapely.Geometry]:
    """A 10 x 10 mm stem 6 mm tall under a 30 x 30 x 2 mm plate: a T."""
    stem = box((10, 10, 6), (10, 10, 0))
    plate = box((30, 30, 2), (0, 0, 6))
    return outlines(trimesh.util.concatenate([stem, plate]))


SETTINGS = SliceSettings.from_mapping({"support.enabled": True})


def test_support_fills_under_the_overhang_and_not_under_the_stem(
    tee: list[shapely.Geometry],
) -> None:
    regions = support_regions(tee, SETTINGS, H)
    assert len(regions) == len(tee)
    bottom = regions[0]
    assert bottom.area > 0.8 * (30 * 30 - 10 * 10)
    assert bottom.contains(shapely.Point(3, 3))
    assert not bottom.intersects(shapely.box(10, 10, 20, 20))
    for region in regions[30:]:  # the plate's own layers need nothing
        assert region.is_empty


def test_support_keeps_its_clearance_from_the_part(tee: list[shapely.Geometry]) -> None:
    regions = support_regions(tee, SETTINGS, H)
    for region, part in zip(regions, tee, strict=True):
        if not region.is_empty and not part.is_empty:
            # round joins are polygons: allow their chord error (under 1 % of the clearance)
            assert region.distance(part) >= 0.99 * SETTINGS.support_clearance


def test_support_stops_a_z_gap_below_the_surface_it_holds(tee: list[shapely.Geometry]) -> None:
    regions = support_regions(tee, SETTINGS, H)
    first_plate = next(i for i, g in enumerate(tee) if g.area > 500)
    assert regions[first_plate - 1].is_empty  # the one-layer gap under the plate
    assert not regions[first_plate - 2].is_empty


def test_a_vertical_walled_cube_needs_no_support() -> None:
    layers = outlines(trimesh.load(DATA / "cube20_xyz.stl"))
    assert all(region.is_empty for region in support_regions(layers, SETTINGS, H))


def test_gentle_slopes_are_self_supporting_and_steep_ones_are_not() -> None:
    # a 45 degree step pyramid: each 0.2 mm layer is 0.2 mm wider on every side
    steps = [box((10 + 0.4 * k, 10 + 0.4 * k, H), (-0.2 * k, -0.2 * k, k * H)) for k in range(20)]
    layers = outlines(trimesh.util.concatenate(steps))
    at_50 = support_regions(layers, SETTINGS, H)  # tan 50 > 1: 45 degrees holds itself
    assert all(region.is_empty for region in at_50)
    strict = SliceSettings.from_mapping({"support.enabled": True, "support.angle": 30})
    at_30 = support_regions(layers, strict, H)
    assert any(not region.is_empty for region in at_30)


def test_support_paths_wall_infill_and_interface_stay_in_the_region(
    tee: list[shapely.Geometry],
) -> None:
    regions = support_regions(tee, SETTINGS, H)
    roofs = support_interfaces(tee, regions, SETTINGS, H)
    bounds = (0.0, 0.0, 30.0, 30.0)
    low = LayerContext(index=2, z=0.6, domain=tee[2], bounds=bounds, settings=SETTINGS)
    paths = support_paths(regions[2], tee[2], low, roofs[2])
    assert set(paths) == {"wall", "infill", "interface"}
    assert not paths["wall"].is_empty
    assert not paths["infill"].is_empty
    assert paths["interface"].is_empty  # far below the plate
    for geom in (paths["wall"], paths["infill"]):
        assert regions[2].buffer(1e-6).covers(geom)
        assert geom.distance(tee[2]) >= 0.99 * SETTINGS.support_clearance

    top = max(i for i, r in enumerate(regions) if not r.is_empty)
    assert not roofs[top].is_empty
    high = LayerContext(
        index=top, z=(top + 1) * H, domain=tee[top], bounds=bounds, settings=SETTINGS
    )
    paths = support_paths(regions[top], tee[top], high, roofs[top])
    assert paths["interface"].length > 0
    assert regions[top].buffer(1e-6).covers(paths["interface"])


@pytest.mark.parametrize("density", [0.1, 0.15, 0.3])
def test_support_infill_density_follows_the_setting(
    tee: list[shapely.Geometry], density: float
) -> None:
    settings = SliceSettings.from_mapping({"support.enabled": True, "support.density": density})
    regions = support_regions(tee, settings, H)
    ctx = LayerContext(index=2, z=0.6, domain=tee[2], bounds=(0, 0, 30, 30), settings=settings)
    infill = support_paths(regions[2], tee[2], ctx)["infill"]
    w = settings.line_width
    inside = regions[2].buffer(-w * (1.0 - settings.infill_overlap))
    # path length per area against 1 / spacing: the eggcrate's few levels per cell
    # quantise it, so within 25 %
    assert infill.length / inside.area * (w / density) == pytest.approx(1.0, abs=0.25)


def test_empty_region_gives_empty_paths() -> None:
    ctx = LayerContext(
        index=0, z=0.2, domain=shapely.box(0, 0, 1, 1), bounds=(0, 0, 1, 1), settings=SETTINGS
    )
    paths = support_paths(shapely.Polygon(), shapely.box(0, 0, 1, 1), ctx)
    assert all(geom.is_empty for geom in paths.values())


@pytest.mark.parametrize(
    ("model", "supported"), [("cube20_xyz.stl", False), ("candle_stand.stl", True)]
)
def test_support_from_the_plans_outlines(model: str, supported: bool) -> None:
    from slicer.plan import SlicePlan

    plan = SlicePlan.from_file(DATA / model, SETTINGS)
    layers = [plan.outline(i) for i in range(plan.layer_count)]
    regions = support_regions(layers, SETTINGS, SETTINGS.layer_height)
    # the cube's engraved letters bridge; the candle stand's plate needs holding up
    assert any(not region.is_empty for region in regions) is supported
    if supported:  # under its overhangs, not a sliver
        assert sum(region.area for region in regions) > 1000.0
