"""Load an STL, check it, repair what is safe, and place it on the bed.

Everything refused raises :class:`~slicer.errors.ModelError` with one specific
sentence; everything repaired is reported as a warning.
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from slicer.errors import ModelError

# an open mesh whose open edges are at most this fraction of all edges is still
# sliced (gaps closed per layer); beyond it the file is refused
MAX_OPEN_EDGE_FRACTION = 0.02


@dataclass(frozen=True)
class PlacedMesh:
    """A checked mesh placed on the bed.

    ``vertices`` (v, 3) float64 mm, min z = 0 and centred on the bed in x, y;
    ``faces`` (f, 3) int64; ``face_body`` (f,) int64 the shell each face
    belongs to (0..bodies-1, in order of first face); ``open_edges`` edges
    used by one face only after repair; ``warnings`` repairs made.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_body: np.ndarray
    bodies: int
    open_edges: int
    warnings: tuple[str, ...]

    @property
    def height(self) -> float:
        """Model height, mm."""
        return float(self.vertices[:, 2].max()) if len(self.vertices) else 0.0

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the placed model, mm."""
        lo = self.vertices[:, :2].min(axis=0)
        hi = self.vertices[:, :2].max(axis=0)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def read_stl(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) float64 and faces (f, 3) int64 of an ASCII or binary STL.

    Raises ModelError for a missing, empty or non-STL file, or coordinates that
    are not finite.
    """
    try:
        data = open(path, "rb").read()  # noqa: SIM115 (one read, then closed)
    except OSError as exc:
        raise ModelError(f"cannot read the file: {exc.strerror or exc}") from exc
    if not data.strip():
        raise ModelError("empty file")
    kind = _stl_kind(data)
    if kind is None:
        raise ModelError("not an STL file (neither binary STL nor ASCII 'solid ... facet')")
    try:
        loaded = trimesh.exchange.stl.load_stl(io.BytesIO(data))
    except Exception as exc:  # trimesh raises many types for malformed input
        raise ModelError(f"not a readable {kind} STL file: {exc}") from exc
    del data
    vertices = np.asarray(loaded.get("vertices", np.empty((0, 3))), dtype=np.float64)
    faces = np.asarray(loaded.get("faces", np.empty((0, 3))), dtype=np.int64)
    if len(faces) == 0:
        raise ModelError("the STL file has no triangles")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise ModelError(f"non-finite coordinates (NaN or infinity) in {bad} vertices")
    return vertices, faces


def _stl_kind(data: bytes) -> str | None:
    """'binary' or 'ASCII' when the bytes look like that kind of STL, else None."""
    if len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        if 84 + 50 * count == len(data) and count > 0:
            return "binary"
    head = data[:1024].lstrip().lower()
    if head.startswith(b"solid") and (b"facet" in data[:4096].lower() or len(data) < 4096):
        return "ASCII"
    return None


def prepare(vertices: np.ndarray, faces: np.ndarray, bed: tuple[float, float, float]) -> PlacedMesh:
    """Merge, repair, validate and place a raw triangle list on the bed.

    Repairs (each reported): merged duplicate vertices, removed degenerate and
    duplicate faces and dangling fins, fixed winding and inverted normals,
    filled small holes. Refuses (ModelError): open after repair beyond a small
    fraction of edges, zero volume, bigger than the bed.
    """
    warnings: list[str] = []
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=True, validate=False)
    del vertices, faces
    removed = _remove_bad_faces(mesh)
    if len(mesh.faces) == 0:
        raise ModelError("no solid triangles left: every triangle is degenerate")
    if removed:
        warnings.append(f"repaired: removed {removed} degenerate, duplicate or dangling faces")
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
        warnings.append("repaired: fixed inconsistent face winding")
    open_edges, total_edges = _edge_counts(mesh)
    _refuse_open(open_edges, total_edges)
    if open_edges:
        before = open_edges
        trimesh.repair.fill_holes(mesh)
        open_edges, total_edges = _edge_counts(mesh)
        if open_edges < before:
            warnings.append(f"repaired: filled small holes ({before - open_edges} open edges)")
    _refuse_open(open_edges, total_edges)
    with np.errstate(all="ignore"):
        volume = float(mesh.volume)
    if volume < 0:
        mesh.invert()
        volume = -volume
        warnings.append("repaired: normals pointed inwards, flipped")
    extents = mesh.extents
    if extents[2] <= 1e-6 or volume <= 1e-9 * max(1.0, float(np.prod(np.maximum(extents, 1e-3)))):
        raise ModelError("zero volume: the model is flat or has no inside")
    if open_edges:
        warnings.append(
            f"mesh is not closed: {open_edges} open edges; gaps are closed layer by layer"
        )
    if (extents[0] > bed[0]) or (extents[1] > bed[1]) or (extents[2] > bed[2]):
        raise ModelError(
            "bigger than the bed: model {:.1f} x {:.1f} x {:.1f} mm, "
            "bed {:g} x {:g} x {:g} mm".format(*extents, *bed)
        )
    verts = np.array(mesh.vertices, dtype=np.float64)
    lo = verts.min(axis=0)
    hi = verts.max(axis=0)
    shift = np.array(
        [bed[0] / 2.0 - (lo[0] + hi[0]) / 2.0, bed[1] / 2.0 - (lo[1] + hi[1]) / 2.0, -lo[2]]
    )
    verts += shift
    faces = np.array(mesh.faces, dtype=np.int64)
    del mesh
    face_body, bodies = _bodies(faces, len(verts))
    return PlacedMesh(verts, faces, face_body, bodies, open_edges, tuple(warnings))


def _refuse_open(open_edges: int, total_edges: int) -> None:
    """Refuse a mesh with more open edges than small gaps closed per layer can fix."""
    if open_edges > MAX_OPEN_EDGE_FRACTION * total_edges:
        raise ModelError(
            f"not watertight after repair: {open_edges} open edges "
            f"({100.0 * open_edges / total_edges:.0f} % of edges)"
        )


def _remove_bad_faces(mesh: trimesh.Trimesh) -> int:
    """Drop faces with repeated vertices, duplicate faces and dangling fins; return how many."""
    faces = mesh.faces
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    )
    srt = np.sort(faces, axis=1)
    _, first = np.unique(srt, axis=0, return_index=True)
    unique = np.zeros(len(faces), dtype=bool)
    unique[first] = True
    keep &= unique
    # a fin: a face with two open edges hanging on an edge shared by 3+ faces
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, inverse, counts = np.unique(edges, axis=0, return_inverse=True, return_counts=True)
    per_face = counts[inverse.reshape(-1)].reshape(-1, 3)
    fin = ((per_face == 1).sum(axis=1) >= 2) & (per_face >= 3).any(axis=1)
    keep &= ~fin
    removed = int((~keep).sum())
    if removed:
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
    return removed


def _edge_counts(mesh: trimesh.Trimesh) -> tuple[int, int]:
    """(edges used by exactly one face, distinct edges)."""
    edges = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    key = edges[:, 0].astype(np.int64) * len(mesh.vertices) + edges[:, 1]
    _, counts = np.unique(key, return_counts=True)
    return int((counts == 1).sum()), len(counts)


def _bodies(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Connected shells: (body of each face (f,) int64 numbered by first face, count)."""
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices,) * 2)
    count, label = connected_components(graph, directed=False)
    face_label = label[faces[:, 0]]
    # renumber in order of first appearance so numbering follows the file
    _, first = np.unique(face_label, return_index=True)
    rank = np.empty(count, dtype=np.int64)
    rank[np.argsort(first)] = np.arange(count)
    return rank[face_label].astype(np.int64), int(count)
