"""Write dogbone.stl: the tensile specimen of the paper's functional-tailoring experiment.

Overall 100 x 30 x 5 mm, lying flat (x along the specimen, z = 0..5). Full-width
ends 0..25 and 75..100 (the outer 12 mm of each is gripped), a 10 mm wide
narrowed section 35..65 holding the 10 x 20 mm gage area (40..60) in its
middle, joined to the ends by 10 mm radius fillets tangent to the narrow
section (the paper gives no shape for them). Run: python make_dogbone.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from slicer.input.stl_binary import write_stl

LENGTH, WIDTH, THICKNESS, GAGE_WIDTH = 100.0, 30.0, 5.0, 10.0
END = 25.0  # full-width end, mm
RADIUS = (WIDTH - GAGE_WIDTH) / 2.0  # fillet radius, mm
SEGMENTS = 48  # per fillet


def half_width(n: int = SEGMENTS) -> tuple[np.ndarray, np.ndarray]:
    """Stations x (m,) mm along the specimen and the half width w(x) (m,) mm there."""
    a = np.linspace(0.0, np.pi / 2.0, n + 1)
    # a quarter circle centred at (35, 15): vertical where it meets the end at x = 25,
    # tangent to the narrow section's edge at x = 35
    left_x = END + RADIUS - RADIUS * np.cos(a)  # 25 -> 35
    left_w = WIDTH / 2.0 - RADIUS * np.sin(a)  # 15 -> 5
    x = np.concatenate(([0.0], left_x, LENGTH - left_x[::-1], [LENGTH]))
    w = np.concatenate(([WIDTH / 2.0], left_w, left_w[::-1], [WIDTH / 2.0]))
    return x, w


def dogbone() -> tuple[np.ndarray, np.ndarray]:
    """Vertices (v, 3) float64 mm and outward-wound faces (f, 3) int64 of the specimen."""
    x, w = half_width()
    m = len(x)
    cy = WIDTH / 2.0
    ring = np.concatenate(
        [np.column_stack((x, cy - w)), np.column_stack((x[::-1], cy + w[::-1]))]
    )  # counter-clockwise seen from above: lower edge left to right, upper right to left
    k = len(ring)
    bottom = np.column_stack((ring, np.zeros(k)))
    top = np.column_stack((ring, np.full(k, THICKNESS)))
    vertices = np.vstack((bottom, top))
    faces = []
    lower = np.arange(m)  # lower edge, station i
    upper = 2 * m - 1 - np.arange(m)  # upper edge, station i
    for i in range(m - 1):
        a, b, c, d = lower[i], lower[i + 1], upper[i + 1], upper[i]
        faces += [[a, c, b], [a, d, c]]  # bottom cap, facing -z
        faces += [[a + k, b + k, c + k], [a + k, c + k, d + k]]  # top cap, facing +z
    for i in range(k):
        j = (i + 1) % k
        faces += [[i, j, j + k], [i, j + k, i + k]]  # sides, facing outwards
    return vertices, np.asarray(faces, dtype=np.int64)


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).with_name("dogbone.stl")
    write_stl(target, *dogbone(), "dogbone 100 x 30 x 5 mm")
    print(f"wrote {target}")
