"""Real-world meshes: exact merge, open meshes, repairs, overlapping shells, vertices on planes."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
import trimesh
from support.slicer_helpers import DATA, write_mesh

from slicer.input.mesh import merge_corners, read_stl
from slicer.input.outline import close_open_chains
from slicer.input.section import cut_block, face_layer_ranges
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


def test_merge_corners_is_exact() -> None:
    corners = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1e-7], [-0.0, 0, 0]],
        dtype=np.float32,
    )[:6]
    vertices, faces = merge_corners(corners)
    assert len(vertices) == 4
    assert faces.tolist() == [[0, 2, 1], [2, 1, 3]] or len(np.unique(faces)) == 4
    # -0 and 0 are one vertex; 1e-7 apart are two
    v, _ = merge_corners(np.array([[0, 0, 0], [-0.0, 0, 0], [0, 0, 1e-7]], dtype=np.float32))
    assert len(v) == 2


def test_loops_close_when_planes_hit_vertices(tmp_path) -> None:
    # a box whose top and a ring of vertices lie exactly on cut planes
    mesh = trimesh.creation.cylinder(radius=5, height=1.0, sections=24)
    mesh.apply_translation((0, 0, 0.5))
    vertices = np.array(mesh.vertices)
    faces = np.array(mesh.faces)
    planes = np.array([0.0, 0.1, 0.5, 1.0])  # on the bottom, between, on the top
    lo, hi = face_layer_ranges(vertices[:, 2], faces, planes)
    chains = cut_block(vertices, faces, planes, lo, hi, 0, len(planes))
    assert chains.closed.all()
    # the plane at z = 0 touches only the bottom: nothing or closed loops
    for layer in (1, 2):
        k = np.flatnonzero(chains.layer == layer)
        assert len(k) == 1
        ring = chains.coords[chains.offsets[k[0]] : chains.offsets[k[0] + 1]]
        # the section is the cylinder's regular 24-gon of circumradius 5: n/2 r^2 sin(2 pi/n)
        polygon_area = 24 / 2 * 5.0**2 * np.sin(2 * np.pi / 24)
        assert shapely.Polygon(ring).area == pytest.approx(polygon_area, rel=1e-6)


@pytest.mark.parametrize("step", [0.5, 12.7, 46.7])
def test_face_at_a_layer_middle_belongs_to_the_layer_above(step: float) -> None:
    # a 10 x 10 block up to ``step`` with a 4 x 4 block on it: the step lies at the
    # middle of a 0.2 mm layer, stored in float32 as STL stores it (46.7 is not exact)
    base = trimesh.creation.box(extents=(10.0, 10.0, step))
    base.apply_translation((0, 0, step / 2.0))
    top = trimesh.creation.box(extents=(4.0, 4.0, 2.0))
    top.apply_translation((0, 0, step + 1.0))
    mesh = trimesh.util.concatenate([base, top])
    vertices = np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)
    settings = SliceSettings()
    assert settings.layer_height == settings.first_layer_height == pytest.approx(0.2)
    plan = SlicePlan.from_mesh(vertices, np.asarray(mesh.faces), settings)
    middle = round((step + 0.1) / 0.2) - 1  # the layer whose middle is the step
    assert plan.layer_z(middle) == pytest.approx(step + 0.1)
    # the tie goes one way for every face of the step, whatever float32 made of it
    assert plan.outline(middle).area == pytest.approx(100.0, rel=1e-3)
    assert plan.outline(middle + 1).area == pytest.approx(16.0, rel=1e-3)


def test_open_bunny_slices_with_closed_gaps() -> None:
    plan = SlicePlan.from_file(DATA / "bunny.stl", SliceSettings())
    assert any("open edges" in w for w in plan.warnings)
    assert any("closed" in w and "gaps" in w for w in plan.warnings)
    # the open base (z < 10.5 mm) still gives solid layers (PrusaSlicer leaves them
    # nearly empty); layer 0 is the bunny's few contact points with the bed
    areas = [plan.outline(i).area for i in range(1, 52)]
    assert min(areas[2:]) > 500.0, areas
    assert all(plan.layer_gcode(i)[1:] for i in range(1, 52))
    # the pocket under the belly, open across 25 mm, is not cut out as a hole
    assert not any(r.area > 100.0 for p in shapely.get_parts(plan.outline(5))
                   for r in map(shapely.Polygon, p.interiors))
    # a closed layer just above the opening is unaffected
    assert plan.outline(60).area > 1000.0


def _arc(cx: float, cy: float, r: float, start: float, stop: float) -> np.ndarray:
    """Points (k, 2) on a circle from angle ``start`` to ``stop`` (radians)."""
    t = np.linspace(start, stop, 60)
    return np.column_stack((cx + r * np.cos(t), cy + r * np.sin(t)))


def test_wide_gaps_close_as_solid_but_never_as_holes() -> None:
    # open arcs missing a quarter (a gap of 14 mm on a radius of 10 mm)
    solid = _arc(0, 0, 10, 0.0, 1.5 * np.pi)  # counter-clockwise: an outer boundary
    pocket = _arc(50, 0, 10, 1.5 * np.pi, 0.0)  # clockwise: a pocket seen through the opening
    loops, closed, dropped = close_open_chains([solid, pocket], 2.0, 60.0, hole_gap=10.0)
    assert (closed, dropped) == (1, 1)
    assert len(loops) == 1
    assert loops[0][0] == pytest.approx(solid[0])
    # a narrow opening closes either way
    narrow = _arc(50, 0, 10, 1.9 * np.pi, 0.1 * np.pi)
    loops, closed, dropped = close_open_chains([narrow], 2.0, 60.0, hole_gap=10.0)
    assert (len(loops), closed, dropped) == (1, 1, 0)


def test_stray_face_and_duplicates_are_repaired(tmp_path) -> None:
    mesh = trimesh.creation.box(extents=(10, 10, 4))
    v = np.array(mesh.vertices)
    f = np.array(mesh.faces)
    # a duplicate face, a degenerate one, and a fin hanging on an edge (as in dragon_100k)
    fin_tip = len(v)
    v = np.vstack([v, [[0, 0, 9.0]]])
    f = np.vstack([f, f[:1], [[0, 0, 1]], [[f[0, 0], f[0, 1], fin_tip]]])
    stl = trimesh.Trimesh(vertices=v, faces=f, process=False)
    plan = SlicePlan.from_file(write_mesh(stl, tmp_path / "dirty.stl"), SliceSettings())
    said = plan.warnings
    assert any(w.startswith("repaired: 1 triangle given twice") for w in said), said
    assert any("with two corners at one point" in w for w in plan.warnings), plan.warnings
    assert any("hanging loose on an edge" in w for w in plan.warnings), plan.warnings
    assert not any("not closed" in w for w in plan.warnings)


def test_inverted_normals_are_flipped(tmp_path) -> None:
    mesh = trimesh.creation.box(extents=(10, 10, 4))
    mesh.invert()
    plan = SlicePlan.from_file(write_mesh(mesh, tmp_path / "inv.stl"), SliceSettings())
    assert any("flipped" in w for w in plan.warnings)
    assert plan.outline(5).area == pytest.approx(100.0, rel=1e-6)


def test_overlapping_shells_are_united(tmp_path) -> None:
    a = trimesh.creation.box(extents=(10, 10, 4))
    b = trimesh.creation.box(extents=(10, 10, 4))
    b.apply_translation((5, 0, 0))
    inner = trimesh.creation.box(extents=(4, 4, 4))  # a shell inside another shell
    path = write_mesh(trimesh.util.concatenate([a, b, inner]), tmp_path / "overlap.stl")
    plan = SlicePlan.from_file(path, SliceSettings())
    assert plan.body_count == 1  # overlapping shells are one object
    outline = plan.outline(10)
    assert outline.is_valid
    assert outline.area == pytest.approx(150.0, rel=1e-6)  # union, not even-odd
    assert len(shapely.get_parts(outline)) == 1
    assert any("made valid" in w for w in plan.warnings)


def test_cavity_shell_stays_a_hole(tmp_path) -> None:
    outer = trimesh.creation.box(extents=(20, 20, 10))
    cavity = trimesh.creation.box(extents=(8, 8, 4))
    cavity.invert()
    path = write_mesh(trimesh.util.concatenate([outer, cavity]), tmp_path / "cavity.stl")
    plan = SlicePlan.from_file(path, SliceSettings())
    assert plan.body_count == 1
    mid = plan.layer_count // 2
    assert plan.outline(mid).area == pytest.approx(400.0 - 64.0, rel=1e-6)
    assert plan.outline(2).area == pytest.approx(400.0, rel=1e-6)


def test_binary_and_ascii_read_the_same(tmp_path) -> None:
    mesh = trimesh.load_mesh(DATA / "featuretype_mm.stl")
    ascii_path = tmp_path / "f.stl"
    ascii_path.write_text(trimesh.exchange.stl.export_stl_ascii(mesh))
    vb, fb = read_stl(DATA / "featuretype_mm.stl")
    va, fa = read_stl(ascii_path)
    assert len(vb) == len(va)
    assert len(fb) == len(fa)
    assert np.allclose(np.sort(vb, axis=0), np.sort(va, axis=0), atol=1e-4)


def test_merge_survives_hash_collisions(monkeypatch) -> None:
    import slicer.input.grouping as grouping

    rng = np.random.default_rng(1)
    corners = rng.integers(0, 4, size=(300, 3)).astype(np.float32)
    expected = len(np.unique(corners, axis=0))
    zero = np.uint64(0)
    monkeypatch.setattr(grouping, "_MIX", (zero, zero, zero))  # every key collides
    vertices, faces = merge_corners(corners)
    assert len(vertices) == expected
    assert np.array_equal(vertices[faces.ravel()], corners.astype(np.float64))
