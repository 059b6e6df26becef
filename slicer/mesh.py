"""Load an STL, check it, repair what is safe, and place it on the bed.

Everything refused raises :class:`~slicer.errors.ModelError` with one specific
sentence; everything repaired is reported as a warning.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

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


# one binary STL record: normal, three corners, attribute bytes (50 bytes)
_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
# triangles parsed per read, to bound memory on big files
_CHUNK = 1 << 18


def read_stl(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) float64 mm and faces (f, 3) int64 of an ASCII or binary STL.

    Binary files are read straight into a float32 corner array in chunks (the
    format is fixed 50-byte records), ASCII files by trimesh's STL reader;
    identical corners are then merged exactly (bitwise equal coordinates, as
    STL writers repeat them). Raises ModelError for a missing, empty or
    non-STL file, or coordinates that are not finite.
    """
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise ModelError(f"cannot read the file: {exc.strerror or exc}") from exc
    if size == 0 or (size <= len(head) and not head.strip()):
        raise ModelError("empty file")
    kind = _stl_kind(head, size)
    if kind is None:
        raise ModelError("not an STL file (neither binary STL nor ASCII 'solid ... facet')")
    corners = _read_binary(path, (size - 84) // 50) if kind == "binary" else _read_ascii(path)
    if len(corners) < 3:
        raise ModelError("the STL file has no triangles")
    finite = np.isfinite(corners).all(axis=1)
    if not finite.all():
        raise ModelError(
            f"non-finite coordinates (NaN or infinity) in {int((~finite).sum())} vertices"
        )
    del finite
    return merge_corners(corners)


def _read_binary(path: str | os.PathLike[str], count: int) -> np.ndarray:
    """Corners (3 count, 3) float32 of a binary STL, read in chunks."""
    out = np.empty((count * 3, 3), dtype=np.float32)
    with open(path, "rb") as fh:
        fh.seek(84)
        done = 0
        while done < count:
            k = min(_CHUNK, count - done)
            records = np.fromfile(fh, dtype=_RECORD, count=k)
            if len(records) < k:
                raise ModelError("truncated binary STL file")
            out[done * 3 : (done + k) * 3] = records["corners"].reshape(-1, 3)
            done += k
    return out


def _read_ascii(path: str | os.PathLike[str]) -> np.ndarray:
    """Corners (3n, 3) of an ASCII STL, parsed by trimesh."""
    import trimesh

    try:
        with open(path, "rb") as fh:
            loaded = trimesh.exchange.stl.load_stl(fh)
    except Exception as exc:  # trimesh raises many types for malformed input
        raise ModelError(f"not a readable ASCII STL file: {exc}") from exc
    corners = np.asarray(loaded.get("vertices", np.empty((0, 3))), dtype=np.float32)
    return corners[: len(corners) // 3 * 3]


# odd 64-bit multipliers of the corner hash (from splitmix64)
_MIX = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB))


def merge_corners(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge bitwise-equal triangle corners: (3n, 3) float -> vertices (v, 3), faces (n, 3).

    Exact: two corners merge only when their float32 coordinates are equal
    (``-0`` and ``0`` alike). Corners are sorted by a 64-bit hash of their
    bits; equal hashes are then checked coordinate by coordinate, and the
    rare hash collision falls back to an exact lexicographic sort. Memory stays
    at a few arrays of 3n 64-bit numbers.
    """
    c32 = np.ascontiguousarray(corners, dtype=np.float32)
    c32 += np.float32(0.0)  # -0 becomes 0 (in place when already float32)
    bits = c32.view(np.uint32)
    key = bits[:, 0].astype(np.uint64)
    key *= _MIX[0]
    tmp = bits[:, 1].astype(np.uint64)
    tmp *= _MIX[1]
    key ^= tmp
    tmp[:] = bits[:, 2]
    tmp *= _MIX[2]
    key ^= tmp
    del tmp
    order = np.argsort(key)  # ties are identical corners: their order does not matter
    key = key[order]
    new = np.empty(len(order), dtype=bool)
    new[0] = True
    np.not_equal(key[1:], key[:-1], out=new[1:])
    del key
    vertices, inverse = _labels(c32, order, new)
    # a hash collision would merge different corners: check every corner against
    # its vertex (sequential reads, lookups in the small vertex table)
    step = 1 << 18
    for a in range(0, len(inverse), step):
        if not (c32[a : a + step] == vertices[inverse[a : a + step]]).all():
            order = np.lexsort((bits[:, 2], bits[:, 1], bits[:, 0]))
            s = bits[order]
            new[1:] = (s[1:] != s[:-1]).any(axis=1)
            del s
            vertices, inverse = _labels(c32, order, new)
            break
    return vertices.astype(np.float64), inverse.reshape(-1, 3)


def _labels(c32: np.ndarray, order: np.ndarray, new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (float32) and each corner's vertex index from a sort ``order`` whose
    runs of equal corners start where ``new`` is True."""
    index = np.cumsum(new, dtype=np.int64)
    index -= 1
    inverse = np.empty(len(order), dtype=np.int64)
    inverse[order] = index
    return c32[order[new]], inverse


def _stl_kind(head: bytes, size: int) -> str | None:
    """'binary' or 'ASCII' when the file (its first bytes and size) looks like that STL."""
    if size >= 84 and len(head) >= 84:
        count = int.from_bytes(head[80:84], "little")
        if 84 + 50 * count == size and count > 0:
            return "binary"
        body = head[84:]
        textual = not body.translate(None, bytes(range(32, 127)) + b"\t\r\n")
        if 84 + 50 * count > size and count > 0 and not textual:
            raise ModelError(
                f"truncated binary STL file: header says {count} triangles, "
                f"the file holds {(size - 84) // 50}"
            )
    text = head.lstrip().lower()
    if text.startswith(b"solid") and (b"facet" in text or size < 4096):
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
    faces, removed, stats = _remove_bad_faces(faces, len(vertices))
    if len(faces) == 0:
        raise ModelError("no solid triangles left: every triangle is degenerate")
    if removed:
        warnings.append(f"repaired: removed {removed} degenerate, duplicate or dangling faces")
    _refuse_open(stats.open, stats.total)
    if not stats.consistent:
        faces = _fix_winding(vertices, faces)
        warnings.append("repaired: fixed inconsistent face winding")
        stats = _edge_stats(faces, len(vertices))
    if stats.open:
        faces, closed = _fill_small_holes(faces, len(vertices), stats.open_keys)
        if closed:
            warnings.append(f"repaired: filled small holes ({closed} open edges)")
            stats = _edge_stats(faces, len(vertices))
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
    # the triple product v0 . (v1 x v2) per face, from contiguous coordinate columns
    x, y, z = (np.ascontiguousarray(vertices[:, k]) for k in range(3))
    total = 0.0
    for a in range(0, len(faces), 1 << 16):
        f = faces[a : a + (1 << 16)]
        i, j, k = f[:, 0], f[:, 1], f[:, 2]
        x1, y1, z1, x2, y2, z2 = x[j], y[j], z[j], x[k], y[k], z[k]
        total += float(
            (x[i] * (y1 * z2 - z1 * y2) + y[i] * (z1 * x2 - x1 * z2) + z[i] * (x1 * y2 - y1 * x2))
            .sum()
        )
    return total / 6.0


def _fix_winding(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces with consistent winding (trimesh's repair; only for meshes that need it)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    trimesh.repair.fix_winding(mesh)
    return np.array(mesh.faces, dtype=np.int64)


def _fill_small_holes(faces: np.ndarray, nv: int, open_keys: np.ndarray) -> tuple[np.ndarray, int]:
    """Close holes bounded by three or four open edges with one or two new faces.

    ``open_keys`` are the sorted undirected keys of the open edges (from
    :func:`_edge_stats`); the faces' directed edges on them, looked up in that
    small array, give each rim edge with its direction. A hole's rim is walked
    through a successor map over those edges (vectorised), and only rims that
    close after three or four steps are filled, wound to match their
    neighbours. Returns the faces (new ones appended) and the number of open
    edges closed.
    """
    n = len(faces)
    ra_parts, rb_parts = [], []
    for j in range(3):
        a = faces[:, j].astype(np.int64)
        b = faces[:, (j + 1) % 3].astype(np.int64)
        und = np.minimum(a, b) * nv + np.maximum(a, b)
        pos = np.minimum(np.searchsorted(open_keys, und), len(open_keys) - 1)
        on_rim = open_keys[pos] == und
        ra_parts.append(a[on_rim])
        rb_parts.append(b[on_rim])
    ra, rb = np.concatenate(ra_parts), np.concatenate(rb_parts)
    if len(ra) == 0 or n == 0:
        return faces, 0
    # the rim continues from rb at the open edge starting there (unique starts only)
    order = np.argsort(ra, kind="stable")
    starts = ra[order]
    unique = np.ones(len(starts), dtype=bool)
    unique[1:] = starts[1:] != starts[:-1]
    unique[:-1] &= starts[1:] != starts[:-1]

    def step(v: np.ndarray) -> np.ndarray:
        i = np.minimum(np.searchsorted(starts, v), len(starts) - 1)
        ok = (starts[i] == v) & unique[i]
        return np.where(ok, rb[order[i]], -1)

    v1 = rb
    v2 = step(v1)
    v3 = np.where(v2 >= 0, step(np.maximum(v2, 0)), -1)
    v4 = np.where(v3 >= 0, step(np.maximum(v3, 0)), -1)
    tri = (v3 == ra) & (ra < np.minimum(v1, v2))  # one face per triangle, from its lowest vertex
    quad = (v4 == ra) & (v3 != ra) & (ra < np.minimum(np.minimum(v1, v2), v3))
    new = [np.stack([ra[tri], v2[tri], v1[tri]], axis=1)]
    new.append(np.stack([ra[quad], v3[quad], v2[quad]], axis=1))
    new.append(np.stack([ra[quad], v2[quad], v1[quad]], axis=1))
    added = np.concatenate(new).astype(np.int64)
    if len(added) == 0:
        return faces, 0
    return np.concatenate([faces, added]), int(3 * tri.sum() + 4 * quad.sum())


def _refuse_open(open_edges: int, total_edges: int) -> None:
    """Refuse a mesh with more open edges than small gaps closed per layer can fix."""
    if open_edges > MAX_OPEN_EDGE_FRACTION * total_edges:
        raise ModelError(
            f"not watertight after repair: {open_edges} open edges "
            f"({100.0 * open_edges / total_edges:.0f} % of edges)"
        )


@dataclass(frozen=True)
class _EdgeStats:
    """Edge counts: used by one face only (open), distinct edges, winding consistent,
    and whether some edge is shared by three or more faces."""

    open: int
    total: int
    consistent: bool
    overshared: bool
    open_keys: np.ndarray  # sorted undirected keys (lo * v + hi) of the open edges


def _edge_stats(faces: np.ndarray, nv: int) -> _EdgeStats:
    """Open edges, distinct edges and winding consistency from sorted integer edge keys.

    Winding is consistent when no directed edge is used twice (each shared
    edge is walked once in each direction). Works in place on one array of 3f
    keys at a time.
    """
    n = len(faces)
    keys = np.empty(3 * n, dtype=np.int64)
    for j in range(3):  # directed edges, one corner column at a time
        part = keys[j * n : (j + 1) * n]
        np.multiply(faces[:, j], nv, out=part)
        part += faces[:, (j + 1) % 3]
    keys.sort()
    repeated = bool((keys[1:] == keys[:-1]).any())
    for j in range(3):  # undirected edges
        a, b = faces[:, j], faces[:, (j + 1) % 3]
        part = keys[j * n : (j + 1) * n]
        np.minimum(a, b, out=part)
        part *= nv
        part += np.maximum(a, b)
    keys.sort()
    starts = np.concatenate(([0], np.flatnonzero(keys[1:] != keys[:-1]) + 1))
    counts = np.diff(np.append(starts, len(keys)))
    single = counts == 1
    return _EdgeStats(
        int(single.sum()),
        len(counts),
        not repeated,
        bool((counts >= 3).any()),
        keys[starts[single]].copy(),
    )


def _remove_bad_faces(faces: np.ndarray, nv: int) -> tuple[np.ndarray, int, _EdgeStats]:
    """Drop faces with repeated vertices, duplicate faces and dangling fins.

    A fin is a face with two open edges hanging on an edge shared by three or
    more faces (a stray triangle, as in ``dragon_100k.stl``); it is looked for
    only when such an edge exists. Returns the kept faces, how many went and
    the edge statistics of what is kept.
    """
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    keep = (f0 != f1) & (f1 != f2) & (f0 != f2)
    lo = np.minimum(np.minimum(f0, f1), f2).astype(np.int64)
    hi = np.maximum(np.maximum(f0, f1), f2).astype(np.int64)
    mid = f0 + f1 + f2 - lo - hi
    if nv < 2_000_000:
        key = (lo * nv + mid) * nv + hi
        order = np.argsort(key, kind="stable")
        key = key[order]
        dup_sorted = key[1:] == key[:-1]
    else:
        order = np.lexsort((hi, mid, lo))
        dup_sorted = (
            (lo[order[1:]] == lo[order[:-1]])
            & (mid[order[1:]] == mid[order[:-1]])
            & (hi[order[1:]] == hi[order[:-1]])
        )
    del lo, hi, mid
    dup = np.zeros(len(faces), dtype=bool)
    dup[order[1:][dup_sorted]] = True
    keep &= ~dup
    del order, dup
    if not keep.all():
        faces = faces[keep]
    removed = int((~keep).sum())
    stats = _edge_stats(faces, nv)
    if stats.overshared:
        fins = _fins(faces, nv)
        if fins.any():
            faces = faces[~fins]
            removed += int(fins.sum())
            stats = _edge_stats(faces, nv)
    return faces, removed, stats


def _fins(faces: np.ndarray, nv: int) -> np.ndarray:
    """Faces with two open edges that hang on an edge shared by three or more faces."""
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    ekey = np.minimum(a, b).astype(np.int64) * nv + np.maximum(a, b)
    _, inverse, counts = np.unique(ekey, return_inverse=True, return_counts=True)
    per_face = counts[inverse].reshape(-1, 3)
    return ((per_face == 1).sum(axis=1) >= 2) & (per_face >= 3).any(axis=1)


def _bodies(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Connected shells: (body of each face (f,) int64 numbered by first face, count).

    Union-find in numpy: each round hooks the larger root of every edge whose
    ends disagree onto the smaller one, then jumps pointers to the roots; a
    mesh settles in a handful of rounds.
    """
    parent = np.arange(n_vertices, dtype=np.int64)
    u = np.concatenate([faces[:, 0], faces[:, 1]])
    v = np.concatenate([faces[:, 1], faces[:, 2]])
    while True:
        pu, pv = parent[u], parent[v]
        differ = pu != pv
        if not differ.any():
            break
        u, v, pu, pv = u[differ], v[differ], pu[differ], pv[differ]
        np.minimum.at(parent, np.maximum(pu, pv), np.minimum(pu, pv))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
    del u, v
    face_label = parent[faces[:, 0]]
    used, first = np.unique(face_label, return_index=True)
    rank = np.empty(len(used), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(used))
    return rank[np.searchsorted(used, face_label)], len(used)
