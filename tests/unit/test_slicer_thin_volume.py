"""Plastic laid against the area it fills, on thin walls and narrow solid regions."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from slicer.paths.layer import SKIN, WALL_OUTER, fill_distance
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

SETTINGS = SliceSettings.from_mapping({"line_width": 0.4, "perimeters": 2})
LAYER = 10  # a middle layer: no top or bottom skin


def _ring_prism(outer: np.ndarray, inner: np.ndarray, height: float) -> SlicePlan:
    """A prism between two counter-clockwise rings of equal point counts (n, 2), mm."""
    n = len(outer)
    ring = np.concatenate([outer, inner])
    verts = np.concatenate([np.c_[ring, np.zeros(2 * n)], np.c_[ring, np.full(2 * n, height)]])
    verts += np.array([100.0, 100.0, 0.0])
    i = np.arange(n)
    j = (i + 1) % n
    o0, i0, o1, i1 = i, n + i, 2 * n + i, 3 * n + i  # bottom/top, outer/inner
    faces = np.concatenate([
        np.c_[o0, i0, j + n], np.c_[o0, j + n, j],  # bottom, facing down
        np.c_[o1, j + 2 * n, j + 3 * n], np.c_[o1, j + 3 * n, i1],  # top, facing up
        np.c_[o0, j, j + 2 * n], np.c_[o0, j + 2 * n, o1],  # outer side
        np.c_[i0, i1, j + 3 * n], np.c_[i0, j + 3 * n, j + n],  # inner side (the hole)
    ])
    return SlicePlan.from_mesh(verts, faces, SETTINGS)


def _laid(paths: list, kinds: set[str] | None = None) -> float:
    """Area the paths' beads lay, length x width, mm^2."""
    total = 0.0
    for p in paths:
        if kinds is None or p.kind in kinds:
            length = float(np.hypot(*np.diff(p.coords, axis=0).T).sum())
            total += length * (SETTINGS.line_width if p.width is None else p.width)
    return total


def _star(radius: float, thickness: float, n: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """A six-pointed star ring ``thickness`` mm across radially (thinner on its slopes)."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = radius + 3.0 * np.cos(6 * a)
    unit = np.c_[np.cos(a), np.sin(a)]
    return r[:, None] * unit, (r - thickness)[:, None] * unit


@pytest.mark.parametrize("thickness", [1.2, 1.1])
def test_thin_star_wall_gets_plastic_across_its_width(thickness: float) -> None:
    # a wall 0.85-1.2 mm across: two 0.4 mm lines left its middle empty (16 % of the
    # twisted vase); the widened outer wall lays the wall's area
    plan = _ring_prism(*_star(15.0, thickness), height=4.0)
    paths = plan.layer_toolpaths(LAYER)
    area = plan.outline(LAYER).area
    assert {p.kind for p in paths} == {WALL_OUTER}
    assert _laid(paths) == pytest.approx(area, rel=0.02)
    # and stays inside the outline: its outer edge is half its width from the outline
    for p in paths:
        off = shapely.distance(shapely.points(p.coords), plan.outline(LAYER).boundary)
        assert np.abs(off - p.width / 2).max() < 0.03


def test_narrow_solid_corners_lay_no_more_than_their_region() -> None:
    # a 6 x 6 mm tower with a 3 mm hole: its corners between the walls are a few
    # lines across; chords and their joints there laid 1.4 times the region's area
    n = 64
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    unit = np.c_[np.cos(a), np.sin(a)]
    square = 3.0 * unit / np.abs(unit).max(axis=1)[:, None]
    plan = _ring_prism(square, 1.5 * unit, height=4.0)
    paths = plan.layer_toolpaths(LAYER)
    outline = plan.outline(LAYER)
    domain = outline.buffer(-fill_distance(SETTINGS), quad_segs=6)
    skin = _laid(paths, {SKIN})
    assert skin > 0
    assert skin <= domain.area * (1 + 1e-9)
    assert _laid(paths) <= 1.08 * outline.area


def test_thin_pin_wall_reaches_its_centre() -> None:
    # a 1.0 mm pin: one outer wall whose bead reaches the centre (W = r), laying its area
    import trimesh

    pin = trimesh.creation.cylinder(radius=0.5, height=4.0, sections=32)
    verts = np.asarray(pin.vertices) + np.array([100.0, 100.0, 2.0])
    plan = SlicePlan.from_mesh(verts, pin.faces, SETTINGS)
    paths = plan.layer_toolpaths(LAYER)
    assert [p.kind for p in paths] == [WALL_OUTER]
    inscribed = 0.5 * np.cos(np.pi / 32)
    assert paths[0].width == pytest.approx(inscribed, abs=0.01)
    assert _laid(paths) == pytest.approx(plan.outline(LAYER).area, rel=0.02)


@pytest.mark.parametrize("thickness", [0.6, 0.5])
def test_wall_thinner_than_two_lines_lays_its_area_not_twice_it(thickness: float) -> None:
    # a tube 0.5-0.6 mm thick: the outer ring's two w-wide sides overlapped and laid
    # 0.8 mm of beads across it (1.3-1.6 times its area: a gyroid sheet's filament was
    # 1.24 times PrusaSlicer's); narrowed, the ring lays the tube's area
    a = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    unit = np.c_[np.cos(a), np.sin(a)]
    plan = _ring_prism(15.0 * unit, (15.0 - thickness) * unit, height=4.0)
    paths = plan.layer_toolpaths(LAYER)
    area = plan.outline(LAYER).area
    assert {p.kind for p in paths} == {WALL_OUTER}
    assert all(p.width is not None and p.width < SETTINGS.line_width for p in paths)
    assert _laid(paths) == pytest.approx(area, rel=0.02)
    for p in paths:
        off = shapely.distance(shapely.points(p.coords), plan.outline(LAYER).boundary)
        assert np.abs(off - p.width / 2).max() < 0.03
