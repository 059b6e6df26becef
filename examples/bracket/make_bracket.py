"""Write bracket.stl: a flat cantilever bracket, 80 x 16 x 6 mm, bent in the plane of its layers.

It lies flat (z = 0..6); the end x 0..8 is bolted down, the free end (x 72..80) carries
a load along -y, so the layers' own plane carries the bending (see bracket.load.toml).
Run: python make_bracket.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from slicer.input.stl_binary import write_stl

LENGTH, WIDTH, THICKNESS = 80.0, 16.0, 6.0


def bracket() -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) float64 mm and outward-wound faces (f, 3) int64 of a box."""
    corners = np.array([[x, y, z] for z in (0.0, THICKNESS) for y in (0.0, WIDTH)
                        for x in (0.0, LENGTH)])
    faces = np.array([
        [0, 2, 3], [0, 3, 1],  # bottom (-z)
        [4, 5, 7], [4, 7, 6],  # top (+z)
        [0, 1, 5], [0, 5, 4],  # y = 0 (-y)
        [2, 6, 7], [2, 7, 3],  # y = W (+y)
        [0, 4, 6], [0, 6, 2],  # x = 0 (-x)
        [1, 3, 7], [1, 7, 5],  # x = L (+x)
    ], dtype=np.int64)
    return corners, faces


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("bracket.stl")
    write_stl(target, *bracket(), "bracket 80 x 16 x 6 mm")
    print(f"wrote {target}")
