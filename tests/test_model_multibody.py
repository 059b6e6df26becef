"""Multibody and unwelded exports as CAD tools write them: stray sheets, inlay bodies
given as loose triangles, overlapping bodies; each prints as its designer meant."""

from __future__ import annotations

import numpy as np
import shapely
import trimesh

from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

BED = (200.0, 200.0, 200.0)


def box(size: tuple[float, float, float], corner: tuple[float, float, float]) -> trimesh.Trimesh:
    """A closed box of ``size`` mm with its lowest corner at ``corner``."""
    b = trimesh.creation.box(size)
    b.apply_translation(np.asarray(size) / 2.0 + corner)
    return b


def stacked(*meshes: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The meshes' vertices and faces in one array each, no vertex shared."""
    vs, fs, n = [], [], 0
    for m in meshes:
        vs.append(np.asarray(m.vertices, dtype=np.float64))
        fs.append(np.asarray(m.faces) + n)
        n += len(m.vertices)
    return np.concatenate(vs), np.concatenate(fs)


def sliced(vertices: np.ndarray, faces: np.ndarray) -> SlicePlan:
    """A plan of the mesh, every layer's G-code made once."""
    plan = SlicePlan.from_mesh(vertices, faces, SliceSettings(), bed=BED)
    for i in range(plan.layer_count):
        plan.layer_gcode(i)
    return plan


def test_a_stray_triangle_beside_a_part_does_not_stop_it():
    # one triangle 1 mm across crossing a layer: its cut is a single segment, which
    # closed on itself was a ring of two points (the real parts' crash)
    sphere = trimesh.creation.icosphere(3, radius=10.0)
    sphere.apply_translation((0.0, 0.0, 10.0))
    sheet = trimesh.Trimesh([[30, 0, 4.5], [31, 0, 4.5], [30.5, 0.5, 6.0]], [[0, 1, 2]])
    plan = sliced(*stacked(sphere, sheet))
    middle = plan.outline(plan.layer_count // 2)
    assert abs(shapely.area(middle) - np.pi * 100.0) < 0.05 * np.pi * 100.0
    assert shapely.area(plan.outline(24)) > 0  # the layer the triangle crosses prints the sphere
