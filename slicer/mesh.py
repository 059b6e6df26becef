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
    """Vertices (v, 3) float64 mm and faces (f, 3) int64 of an ASCII or binary STL.

    Parsed by trimesh; identical corners are merged exactly (bitwise equal
    coordinates, as STL writers repeat them). Raises ModelError for a missing,
    empty or non-STL file, or coordinates that are not finite.
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
    corners = np.asarray(loaded.get("vertices", np.empty((0, 3))))
    del loaded
    if len(corners) < 3:
        raise ModelError("the STL file has no triangles")
    corners = corners[: len(corners) // 3 * 3]
    if not np.isfinite(corners).all():
        bad = int((~np.isfinite(corners)).any(axis=1).sum())
        raise ModelError(f"non-finite coordinates (NaN or infinity) in {bad} vertices")
    del data
    return merge_corners(corners)


def merge_corners(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge bitwise-equal triangle corners: (3n, 3) float -> vertices (v, 3), faces (n, 3).

    Exact: two corners merge only when their coordinates are equal (``-0`` and
    ``0`` alike). Sorting two 64-bit keys keeps memory to a few arrays of 3n.
    """
    c32 = np.ascontiguousarray(corners, dtype=np.float32) + np.float32(0.0)
    bits = c32.view(np.uint32).astype(np.uint64)
    key_xy = (bits[:, 0] << np.uint64(32)) | bits[:, 1]
    key_z = bits[:, 2]
    del bits
    order = np.lexsort((key_z, key_xy))
    kx, kz = key_xy[order], key_z[order]
    new = np.ones(len(order), dtype=bool)
    new[1:] = (kx[1:] != kx[:-1]) | (kz[1:] != kz[:-1])
    del kx, kz, key_xy, key_z
    index = np.cumsum(new) - 1
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = index
    vertices = c32[order[new]].astype(np.float64)
    return vertices, inverse.reshape(-1, 3)


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
    """Repair, validate and place a merged mesh on the bed.

    ``vertices`` (v, 3) float64 mm, ``faces`` (f, 3) int64. Repairs (each
    reported): removed degenerate and duplicate faces and dangling fins, fixed
    winding and inverted normals, filled small holes. Refuses (ModelError):
    open after repair beyond a small fraction of edges, zero volume, bigger
    than the bed.
    """
    warnings: list[str] = []
    faces, removed = _remove_bad_faces(faces, len(vertices))
    if len(faces) == 0:
        raise ModelError("no solid triangles left: every triangle is degenerate")
    if removed:
        warnings.append(f"repaired: removed {removed} degenerate, duplicate or dangling faces")
    stats = _edge_stats(faces, len(vertices))
    _refuse_open(stats.open, stats.total)
    if stats.open or not stats.consistent:
        vertices, faces, stats, notes = _trimesh_repairs(vertices, faces, stats)
        warnings.extend(notes)
        _refuse_open(stats.open, stats.total)
    with np.errstate(all="ignore"):
        volume = signed_volume(vertices, faces)
    if volume < 0:
        faces = faces[:, ::-1].copy()
        volume = -volume
        warnings.append("repaired: normals pointed inwards, flipped")
    lo = vertices.min(axis=0)
    hi = vertices.max(axis=0)
    extents = hi - lo
    if extents[2] <= 1e-6 or not volume > 1e-9 * max(
        1.0, float(np.prod(np.maximum(extents, 1e-3)))
    ):
        raise ModelError("zero volume: the model is flat or has no inside")
    if stats.open:
        warnings.append(
            f"mesh is not closed: {stats.open} open edges; gaps are closed layer by layer"
        )
    if (extents[0] > bed[0]) or (extents[1] > bed[1]) or (extents[2] > bed[2]):
        raise ModelError(
            "bigger than the bed: model {:.1f} x {:.1f} x {:.1f} mm, "
            "bed {:g} x {:g} x {:g} mm".format(*extents, *bed)
        )
    shift = np.array(
        [bed[0] / 2.0 - (lo[0] + hi[0]) / 2.0, bed[1] / 2.0 - (lo[1] + hi[1]) / 2.0, -lo[2]]
    )
    vertices = vertices + shift
    face_body, bodies = _bodies(faces, len(vertices))
    return PlacedMesh(vertices, faces, face_body, bodies, stats.open, tuple(warnings))


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by the faces, mm^3 (negative when the normals point inwards)."""
    total = 0.0
    for a in range(0, len(faces), 1 << 20):
        f = faces[a : a + (1 << 20)]
        v0, v1, v2 = vertices[f[:, 0]], vertices[f[:, 1]], vertices[f[:, 2]]
        total += float(np.einsum("ij,ij->", v0, np.cross(v1, v2)))
    return total / 6.0


@dataclass(frozen=True)
class _EdgeStats:
    """Edge counts: used by one face only (open), distinct edges, winding consistent."""

    open: int
    total: int
    consistent: bool


def _edge_stats(faces: np.ndarray, nv: int) -> _EdgeStats:
    """Open edges, distinct edges and winding consistency from integer edge keys.

    Winding is consistent when no directed edge is used twice (each shared
    edge is walked once in each direction).
    """
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    directed = np.sort(a.astype(np.int64) * nv + b)
    undirected = np.sort(np.minimum(a, b).astype(np.int64) * nv + np.maximum(a, b))
    repeated = bool((directed[1:] == directed[:-1]).any())
    starts = np.flatnonzero(np.concatenate(([True], undirected[1:] != undirected[:-1])))
    counts = np.diff(np.append(starts, len(undirected)))
    return _EdgeStats(int((counts == 1).sum()), len(counts), not repeated)


def _trimesh_repairs(
    vertices: np.ndarray, faces: np.ndarray, stats: _EdgeStats
) -> tuple[np.ndarray, np.ndarray, _EdgeStats, list[str]]:
    """The rarer repairs, with trimesh: fix winding, fill small holes."""
    notes = []
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    if not stats.consistent:
        trimesh.repair.fix_winding(mesh)
        notes.append("repaired: fixed inconsistent face winding")
    if stats.open:
        trimesh.repair.fill_holes(mesh)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    after = _edge_stats(faces, len(vertices))
    if after.open < stats.open:
        notes.append(f"repaired: filled small holes ({stats.open - after.open} open edges)")
    return vertices, faces, after, notes


def _refuse_open(open_edges: int, total_edges: int) -> None:
    """Refuse a mesh with more open edges than small gaps closed per layer can fix."""
    if open_edges > MAX_OPEN_EDGE_FRACTION * total_edges:
        raise ModelError(
            f"not watertight after repair: {open_edges} open edges "
            f"({100.0 * open_edges / total_edges:.0f} % of edges)"
        )


def _remove_bad_faces(faces: np.ndarray, nv: int) -> tuple[np.ndarray, int]:
    """Drop faces with repeated vertices, duplicate faces and dangling fins.

    A fin is a face with two open edges hanging on an edge shared by three or
    more faces (a stray triangle). Returns the kept faces and how many went.
    """
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    )
    srt = np.sort(faces, axis=1).astype(np.int64)
    if nv < 2_000_000:
        key = (srt[:, 0] * nv + srt[:, 1]) * nv + srt[:, 2]
        order = np.argsort(key, kind="stable")
        ks = key[order]
        dup = np.zeros(len(faces), dtype=bool)
        dup[order[1:]] = ks[1:] == ks[:-1]
    else:
        order = np.lexsort((srt[:, 2], srt[:, 1], srt[:, 0]))
        s2 = srt[order]
        dup = np.zeros(len(faces), dtype=bool)
        dup[order[1:]] = (s2[1:] == s2[:-1]).all(axis=1)
    keep &= ~dup
    del srt
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    ekey = np.minimum(a, b).astype(np.int64) * nv + np.maximum(a, b)
    ekey[~np.repeat(keep, 3)] = -1
    _, inverse, counts = np.unique(ekey, return_inverse=True, return_counts=True)
    per_face = counts[inverse].reshape(-1, 3)
    fin = ((per_face == 1).sum(axis=1) >= 2) & (per_face >= 3).any(axis=1)
    keep &= ~fin
    removed = int((~keep).sum())
    if removed:
        faces = faces[keep]
    return faces, removed


def _bodies(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Connected shells: (body of each face (f,) int64 numbered by first face, count)."""
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices,) * 2)
    count, label = connected_components(graph, directed=False)
    face_label = label[faces[:, 0]]
    # renumber in order of first appearance so numbering follows the file
    used, first = np.unique(face_label, return_index=True)
    rank = np.full(count, -1, dtype=np.int64)
    rank[used[np.argsort(first)]] = np.arange(len(used))
    return rank[face_label], len(used)
