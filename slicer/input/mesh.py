"""Load an STL, check it, repair what is safe, and place it on the bed.

Everything refused raises :class:`~slicer.errors.ModelError` with one specific
sentence; everything repaired is reported as a warning.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slicer.errors import ModelError
from slicer.input import repair, shells
from slicer.input.grouping import group_rows
from slicer.input.stl_ascii import read_ascii_corners

# an open mesh whose open edges are at most this fraction of all edges is still
# sliced (gaps closed per layer); beyond it the file is refused
MAX_OPEN_EDGE_FRACTION = 0.02
# ends of open edges closer than this (mm) are one corner written twice (a CAD tool
# writing each body or patch on its own): far below a printable detail, above the
# float32 rounding of coordinates up to a few metres
WELD_TOLERANCE = 1e-3


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
    format is fixed 50-byte records), ASCII files by :mod:`slicer.input.stl_ascii`;
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
    vertices, inverse = _merge(corners)
    del corners  # the corners go before the faces widen to int64
    return vertices, inverse.astype(np.int64)


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


def merge_corners(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge bitwise-equal triangle corners: (3n, 3) float -> vertices (v, 3), faces (n, 3).

    Exact: two corners merge only when their float32 coordinates are equal
    (``-0`` and ``0`` alike); see :func:`slicer.input.grouping.group_rows`.
    """
    vertices, inverse = _merge(corners)
    return vertices, inverse.astype(np.int64)


def _merge(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`merge_corners` with faces in the sort's index type (int32 below 2^31
    corners: the largest array of the read stays half as big). ``corners`` is
    changed in place when it is float32 already (``-0`` becomes ``0``)."""
    c32 = np.ascontiguousarray(corners, dtype=np.float32)
    c32 += np.float32(0.0)  # -0 becomes 0 (in place when already float32)
    order, new = group_rows(c32.view(np.uint32))
    vertices = np.take(c32, order[new], axis=0).astype(np.float64)
    # each corner's vertex: the running count of groups, scattered back a step at
    # a time (no full array of sorted-position labels)
    inverse = np.empty(len(order), dtype=order.dtype)
    done = 0
    step = 1 << 18
    for a in range(0, len(order), step):
        index = np.cumsum(new[a : a + step], dtype=order.dtype)
        index += done - 1
        inverse[order[a : a + step]] = index
        done = int(index[-1]) + 1
    return vertices, inverse.reshape(-1, 3)


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


def prepare(
    vertices: np.ndarray, faces: np.ndarray, bed: tuple[float, float, float],
    in_place: bool = False,
) -> PlacedMesh:
    """Repair, validate and place a merged mesh on the bed.

    ``vertices`` (v, 3) float64 mm, ``faces`` (f, 3) int64. Repairs (each
    reported): removed degenerate and duplicate faces and dangling fins, fixed
    winding and inverted normals, filled small holes. Refuses (ModelError):
    open after repair beyond a small fraction of edges, zero volume, bigger
    than the bed. With ``in_place`` the vertices are moved onto the bed in
    ``vertices`` itself (a float64 array the caller hands over).
    """
    warnings: list[str] = []
    faces, removed, stats = _remove_bad_faces(faces, len(vertices))
    if len(faces) == 0:
        raise ModelError("no solid triangles left: every triangle is degenerate")
    if stats.open:
        welded, merged = repair.weld_open_vertices(
            vertices, faces, stats.open_keys, WELD_TOLERANCE)
        if merged:
            was_open = stats.open
            faces, more, stats = _remove_bad_faces(welded, len(vertices))
            removed = _add_counts(removed, more)
            warnings.append(
                f"repaired: {merged:,} corners that nearly met (within {WELD_TOLERANCE:g} mm) "
                f"welded, closing {was_open - stats.open:,} of {was_open:,} open edges")
    warnings.extend(_removed_lines(removed))
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
    if stats.open:
        face_body, bodies = _bodies(faces, len(vertices))
        if bodies > 1:
            drop, lines = shells.unclosed_bodies(
                vertices, faces, face_body, bodies, stats.open_keys)
            if drop.any():
                faces = faces[~drop]
                warnings.extend(lines)
                stats = _edge_stats(faces, len(vertices))
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
    if in_place:  # the caller's array is moved, not copied (large files)
        vertices += shift
    else:
        vertices = vertices + shift
    face_body, bodies = _bodies(faces, len(vertices))
    return PlacedMesh(vertices, faces, face_body, bodies, stats.open, tuple(warnings))


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume enclosed by the faces, mm^3 (negative when the normals point inwards)."""
    # the triple product v0 . (v1 x v2) per face, from rows gathered whole (np.take
    # reads each corner's row at once, unlike indexing the coordinates one by one)
    total = 0.0
    for a in range(0, len(faces), 1 << 16):
        t = np.take(vertices, faces[a : a + (1 << 16)], axis=0)  # (k, 3, 3)
        total += float(np.einsum("ij,ij->", t[:, 0], np.cross(t[:, 1], t[:, 2])))
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
    # masks over the sorted keys (no index arrays): a run of equal keys is one edge
    m = len(keys)
    first = np.ones(m + 1, dtype=bool)  # first[i]: keys[i] starts a run (first[m]: the end)
    np.not_equal(keys[1:], keys[:-1], out=first[1:m])
    single = first[:m] & first[1:]
    long_runs = np.zeros(m, dtype=bool)  # runs of three or more, marked at their start
    if m >= 3:
        np.equal(keys[2:], keys[:-2], out=long_runs[: m - 2])
        long_runs &= first[:m]
    return _EdgeStats(
        int(single.sum()),
        int(first[:m].sum()),
        not repeated,
        int(long_runs.sum()),
        keys[single],
    )


def _remove_bad_faces(
    faces: np.ndarray, nv: int
) -> tuple[np.ndarray, tuple[int, int, int, int], _EdgeStats]:
    """Drop faces with repeated vertices, duplicate faces and dangling fins.

    A fin is a face with two open edges hanging on an edge shared by three or
    more faces (a stray triangle, as in ``dragon_100k.stl``); it is looked for
    only when such an edge exists. Returns the kept faces, how many went of
    each kind (degenerate, copies wound the same way, faces cancelled by a copy
    wound the other way, fins) and the edge statistics of what is kept.
    """
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    keep = (f0 != f1) & (f1 != f2) & (f0 != f2)
    degenerate = int((~keep).sum())
    copies = cancelled = 0
    corners = faces.astype(np.int32 if nv < 2**31 else np.int64)
    corners.sort(axis=1)
    order, first = group_rows(corners)
    del corners
    if not first.all():
        kept, copies, cancelled = _kept_copies(faces, order, first, keep)
        keep &= kept
    del order, first
    if not keep.all():
        faces = faces[keep]
    stats = _edge_stats(faces, nv)
    fin_count = 0
    if stats.overshared:
        fins = _fins(faces, nv)
        if fins.any():
            faces = faces[~fins]
            fin_count = int(fins.sum())
            stats = _edge_stats(faces, nv)
    return faces, (degenerate, copies, cancelled, fin_count), stats


def _triangles(n: int) -> str:
    return f"{n:,} triangle" if n == 1 else f"{n:,} triangles"


def _add_counts(a: tuple[int, int, int, int], b: tuple[int, int, int, int]
                ) -> tuple[int, int, int, int]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3])


def _removed_lines(removed: tuple[int, int, int, int]) -> list[str]:
    """The faces left out, in words, one line per kind that occurred."""
    degenerate, copies, cancelled, fins = removed
    lines = []
    if degenerate:
        lines.append(f"repaired: {_triangles(degenerate)} with two corners at one point left out")
    if copies:
        lines.append(f"repaired: {_triangles(copies)} given twice: one copy of each kept")
    if cancelled:
        lines.append(
            f"repaired: {_triangles(cancelled)} given once each way (walls of no thickness "
            "where bodies meet) left out")
    if fins:
        lines.append(f"repaired: {_triangles(fins)} hanging loose on an edge left out")
    return lines


def _kept_copies(
    faces: np.ndarray, order: np.ndarray, first: np.ndarray, valid: NDArray[np.bool_]
) -> tuple[NDArray[np.bool_], int, int]:
    """Which faces stay of those given more than once (same three corners): (f,) bool,
    and how many went as copies wound the same way and as cancelled pairs.

    ``order``/``first`` group the faces by their sorted corners
    (:func:`slicer.input.grouping.group_rows`). Copies wound the same way are one face
    given twice: the first stays. A face given once each way is a wall of no
    thickness (an exporter's double wall where two bodies meet, or an inlay
    body's face written with the body it sits in): the two cancel in the count
    of surfaces around any point, so both go; of a group with more one way than
    the other, the first face wound the majority's way stays.
    """
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    # +1 for corners in ascending cyclic order (a < b < c, b < c < a, c < a < b), else -1
    ascents = (a < b).astype(np.int8) + (b < c) + (c < a)
    sign = np.where(ascents == 2, 1, -1)[order]
    group = np.cumsum(first) - 1
    net = np.bincount(group, weights=sign)
    want = np.sign(net)[group]
    candidate = np.flatnonzero((sign == want) & (want != 0))
    _, pick = np.unique(group[candidate], return_index=True)
    keep = np.zeros(len(faces), dtype=bool)
    keep[order[candidate[pick]]] = True
    size = np.bincount(group)
    real = valid[order]  # degenerate faces are counted as such, not as copies
    gone = np.bincount(group, weights=real) - (net != 0)
    cancelled = int((size - np.abs(net))[size > 1].sum())
    return keep, max(0, int(gone[size > 1].sum()) - cancelled), cancelled


def _fins(faces: np.ndarray, nv: int) -> NDArray[np.bool_]:
    """Faces with two open edges that hang on an edge shared by three or more faces."""
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    ekey = np.minimum(a, b).astype(np.int64) * nv + np.maximum(a, b)
    _, inverse, counts = np.unique(ekey, return_inverse=True, return_counts=True)
    per_face = counts[inverse].reshape(-1, 3)
    fins: NDArray[np.bool_] = ((per_face == 1).sum(axis=1) >= 2) & (per_face >= 3).any(axis=1)
    return fins


def _jump(parent: np.ndarray) -> np.ndarray:
    """Every node pointed straight at its root (pointer jumping until nothing moves)."""
    while True:
        jumped = parent[parent]
        if np.array_equal(jumped, parent):
            return parent
        parent = jumped


def _bodies(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """Connected shells: (body of each face (f,) int64 numbered by first face, count).

    Union-find in numpy: each round hooks the larger root of every edge whose
    ends disagree onto the smaller one, then jumps pointers to the roots; a
    mesh settles in a handful of rounds.
    """
    itype = np.int32 if n_vertices < 2**31 else np.int64
    parent = np.arange(n_vertices, dtype=itype)
    f = len(faces)
    u = np.empty(2 * f, dtype=itype)
    v = np.empty(2 * f, dtype=itype)
    u[:f], u[f:] = faces[:, 0], faces[:, 1]
    v[:f], v[f:] = faces[:, 1], faces[:, 2]
    # first round: every vertex is its own root, so hook straight from the edges
    parent[np.maximum(u, v)] = np.minimum(u, v)
    parent = _jump(parent)
    while True:
        pu = parent[u]
        pv = parent[v]
        differ = pu != pv
        if not differ.any():
            break
        if not differ.all():  # one array at a time: bounded temporaries
            u = u[differ]
            v = v[differ]
            pu = pu[differ]
            pv = pv[differ]
        del differ
        # hook each larger root onto a smaller one (any: the last write wins); a
        # component ends labelled by its lowest vertex whichever hooks won
        hi = np.maximum(pu, pv)
        np.minimum(pu, pv, out=pu)
        del pv
        parent[hi] = pu
        del hi, pu
        parent = _jump(parent)
    del u, v
    roots = np.flatnonzero(parent == np.arange(n_vertices))  # ascending
    comp = np.searchsorted(roots, parent[faces[:, 0]])  # each face's component
    del parent
    first = np.full(len(roots), f, dtype=np.int64)
    first[comp[::-1]] = np.arange(f - 1, -1, -1)  # the last write is the lowest face
    used = np.flatnonzero(first < f)
    rank = np.zeros(len(roots), dtype=np.int64)
    rank[used[np.argsort(first[used])]] = np.arange(len(used))
    return rank[comp], len(used)
