"""Write a triangle mesh as a binary STL (the project's generated models and tests)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def write_stl(
    path: str | os.PathLike[str], vertices: np.ndarray, faces: np.ndarray, title: str = ""
) -> None:
    """Write ``vertices`` (v, 3) float mm and ``faces`` (f, 3) int (wound outwards) as a
    binary STL at ``path``, each facet with its unit normal; ``title`` goes in the
    80-byte header (ASCII, cut to fit)."""
    tri = np.asarray(vertices)[np.asarray(faces, dtype=np.int64)].astype("<f4")
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # float32, as stored
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    records = np.zeros(len(tri), dtype=RECORD)
    records["normal"] = normal / np.where(length > 0, length, 1.0)
    records["corners"] = tri
    header = title.encode("ascii", "replace")[:80].ljust(80, b" ")
    count = np.array([len(tri)], dtype="<u4").tobytes()
    Path(path).write_bytes(header + count + records.tobytes())
