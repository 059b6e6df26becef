"""Inward offsets: convex polygons made in numpy are the exact inset, the rest GEOS's buffer."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from slicer.geometry.inset import _convex_insets, inset


def _half_planes(polygon: shapely.Polygon, d: float) -> shapely.Geometry:
    """The inset by its definition: the polygon's edges' half-planes moved in by ``d``,
    intersected one by one (a reference, slow)."""
    ring = shapely.get_coordinates(polygon.exterior)[:-1]
    if not shapely.is_ccw(polygon.exterior):
        ring = ring[::-1]
    big = 1e3
    region = shapely.box(-big, -big, big, big)
    for p, q in zip(ring, np.roll(ring, -1, axis=0), strict=True):
        u = (q - p) / np.hypot(*(q - p))
        n = np.array([-u[1], u[0]])  # inward: the inside lies left of anticlockwise edges
        a = p + d * n
        region = region.intersection(
            shapely.Polygon([a - big * u, a + big * u, a + big * (u + n), a - big * (u - n)]))
    return region


def _convex(count: int, seed: int) -> list[shapely.Polygon]:
    """Convex polygons: points on ellipses at jittered angles, either orientation."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        n = rng.integers(3, 40)
        t = (np.arange(n) + rng.uniform(-0.3, 0.3, n)) * (2.0 * np.pi / n)
        a, b = rng.uniform(0.3, 5.0, 2)
        pts = np.column_stack([a * np.cos(t), b * np.sin(t)]) + rng.uniform(-50, 50, 2)
        polygon = shapely.Polygon(pts if k % 2 else pts[::-1])
        if polygon.is_valid and polygon.area > 0:
            out.append(polygon)
    return out


@pytest.mark.parametrize("d", [0.2, 0.6, 1.0])
def test_a_convex_polygons_inset_is_its_moved_half_planes(d: float) -> None:
    polygons = np.array(_convex(300, seed=int(d * 10)), dtype=object)
    _, made_here = _convex_insets(polygons, np.full(len(polygons), d))
    assert made_here.all()  # none left to GEOS
    got = inset(polygons, d, 6)
    assert shapely.is_valid(got).all()
    made = got[~shapely.is_empty(got)]
    assert len(made) > 50
    assert not shapely.is_ccw(shapely.get_exterior_ring(made)).any()  # clockwise, as GEOS
    for polygon, mine in zip(polygons, got, strict=True):
        want = _half_planes(polygon, d)
        assert mine.symmetric_difference(want).area < 1e-9
        # GEOS's buffer is the same region but for what its input simplification drops
        geos = shapely.buffer(polygon, -d, quad_segs=6)
        assert mine.symmetric_difference(geos).area <= 0.01 * d * polygon.length


def test_a_collapsed_inset_is_empty_where_geos_leaves_a_speck() -> None:
    a = np.linspace(0.0, 2.0 * np.pi, 17)[:-1]
    pin = shapely.Polygon(np.column_stack([0.6 * np.cos(a), 0.6 * np.sin(a)]))  # inradius 0.588
    assert shapely.buffer(pin, -0.6, quad_segs=6).area > 0  # a speck
    got = inset(np.array([pin, shapely.box(0, 0, 1, 5)], dtype=object), 0.6, 6)
    assert got[0].is_empty
    assert got[0].geom_type == "Polygon"
    assert got[1].is_empty


def test_other_polygons_are_geos_buffers_and_distances_may_differ() -> None:
    holed = shapely.box(0, 0, 10, 10).difference(shapely.box(4, 4, 6, 6))
    ell = shapely.Polygon([(0, 0), (6, 0), (6, 2), (2, 2), (2, 6), (0, 6)])  # a reflex corner
    square = shapely.box(20, 0, 24, 4)
    polygons = np.array([holed, ell, square, shapely.Polygon()], dtype=object)
    d = np.array([0.5, 0.3, 0.5, 0.5])
    got = inset(polygons, d, 6)
    for k in range(2):
        assert shapely.equals_exact(got[k], shapely.buffer(polygons[k], -d[k], quad_segs=6), 0.0)
    assert got[2].symmetric_difference(shapely.box(20.5, 0.5, 23.5, 3.5)).area < 1e-12
    assert got[3].is_empty
