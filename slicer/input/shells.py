"""Bodies of a multibody file that cannot be closed: found, named by size, left out.

A CAD export can carry a stray surface beside the part (a construction sheet, a
face left from an edit): it encloses nothing, so it cannot be printed, and on its
own it made a whole file look open. Such a body is left out, reported by its
number and size, and the rest prints, as PrusaSlicer and CuraEngine print it.
"""

from __future__ import annotations

import numpy as np

# a body whose open edges are more than this fraction of its edges cannot be closed
# layer by layer (the same bound the whole mesh is held to)
OPEN_FRACTION = 0.02
# an open body whose faces mostly face one way (its vector area over half its area)
# is a sheet: it bounds no inside, not even layer by layer
SHEET_FRACTION = 0.5


def open_edges_per_face(faces: np.ndarray, nv: int, open_keys: np.ndarray) -> np.ndarray:
    """How many of each face's edges are open, (f,) int64; ``open_keys`` sorted
    undirected edge keys (``lo * nv + hi``) of the open edges."""
    count = np.zeros(len(faces), dtype=np.int64)
    if len(open_keys) == 0:
        return count
    for j in range(3):
        a = faces[:, j].astype(np.int64)
        b = faces[:, (j + 1) % 3].astype(np.int64)
        key = np.minimum(a, b) * nv + np.maximum(a, b)
        pos = np.minimum(np.searchsorted(open_keys, key), len(open_keys) - 1)
        count += open_keys[pos] == key
    return count


def unclosed_bodies(
    vertices: np.ndarray, faces: np.ndarray, face_body: np.ndarray, bodies: int,
    open_keys: np.ndarray,
) -> tuple[np.ndarray, list[str]]:
    """Which faces belong to bodies that cannot be closed, and one line on each.

    ``face_body`` (f,) numbers the connected bodies ``0..bodies-1``. A body is
    left out when more than :data:`OPEN_FRACTION` of its edges are open and it
    is a sheet (:data:`SHEET_FRACTION`), as long as some body stays; a tube or a
    bowl open at its ends stays, closed layer by layer; when every body is that
    open, none is left out (the whole mesh is then judged as before). Returns
    ``drop`` (f,) bool and the report lines, e.g. ``"body 2 of 2 (an open
    surface of 1 triangle, 1.0 x 0.5 x 1.5 mm): encloses nothing, left out"``.
    """
    per_face = open_edges_per_face(faces, len(vertices), open_keys)
    open_count = np.bincount(face_body, weights=per_face, minlength=bodies)
    face_count = np.bincount(face_body, minlength=bodies)
    # each face has three edges, each closed edge shared by two faces
    edge_count = np.maximum(1.0, (3.0 * face_count + open_count) / 2.0)
    # the vector area (sum of normal times area) of a closed surface is zero, as of a
    # tube open at both ends, whose layers still close; of a sheet it is its area
    t = vertices[faces]
    normal_area = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]) / 2.0
    area = np.bincount(face_body, weights=np.linalg.norm(normal_area, axis=1), minlength=bodies)
    vector = np.stack(
        [np.bincount(face_body, weights=normal_area[:, j], minlength=bodies) for j in range(3)],
        axis=1)
    one_sided = np.linalg.norm(vector, axis=1) > SHEET_FRACTION * area
    bad = (open_count > OPEN_FRACTION * edge_count) & one_sided
    drop = np.zeros(len(faces), dtype=bool)
    if not bad.any() or bad.all():
        return drop, []
    drop = bad[face_body]
    lines = []
    listed = np.flatnonzero(bad)
    for b in listed[:_LISTED]:
        n = int(face_count[b])
        lines.append(
            f"body {b + 1} of {bodies} (an open surface of {n:,} "
            f"{'triangle' if n == 1 else 'triangles'}, {_size(vertices, faces[face_body == b])}):"
            " encloses nothing, left out"
        )
    rest = listed[_LISTED:]
    if len(rest):
        n = int(face_count[rest].sum())
        lines.append(
            f"{len(rest):,} more open surfaces ({n:,} triangles, within "
            f"{_size(vertices, faces[bad[face_body] & np.isin(face_body, rest)])}): "
            "enclose nothing, left out"
        )
    return drop, lines


# bodies named one by one in the report; the rest are summed up in one line
_LISTED = 3


def _size(vertices: np.ndarray, faces: np.ndarray) -> str:
    """``"1.0 x 0.5 x 1.5 mm"``: the extent of the faces' corners."""
    pts = vertices[np.unique(faces)]
    size = pts.max(axis=0) - pts.min(axis=0)
    return f"{size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} mm"
