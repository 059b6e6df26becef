"""Load an STL, check it, repair what is safe, and place it on the bed.

Everything refused raises :class:`~slicer.errors.ModelError` with one specific
sentence; everything repaired is reported as a warning.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from slicer import repair
from slicer.errors import ModelError
from slicer.stl_ascii import read_ascii_corners

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
    format is fixed 50-byte records), ASCII files by :mod:`slicer.stl_ascii`;
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
    if kind == "binary":
        corners = _read_binary(path, (size - 84) // 50)
    else:
        corners = read_ascii_corners(path)
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
        faces, flipped = repair.fix_winding(vertices, faces)
        if flipped:
            warnings.append(f"repaired: fixed inconsistent face winding ({flipped} faces turned)")
            stats = _edge_stats(faces, len(vertices))
    if stats.overshared:
        n = stats.overshared
        warnings.append(
            f"{n} {'edge is' if n == 1 else 'edges are'} shared by more than two faces "
            "(bodies touching along an edge): sliced as touching bodies"
        )
    if stats.open:
        faces, closed = repair.fill_small_holes(faces, len(vertices), stats.open_keys)
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
    overshared: int  # edges shared by three or more faces
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
        int((counts >= 3).sum()),
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
