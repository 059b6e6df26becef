"""A small stroke font for the corpus: letters as strokes on a 4 x 6 grid, buffered to solids."""

from __future__ import annotations

import numpy as np

# each glyph: strokes, each a list of (x, y) grid points joined by straight lines
_GLYPHS: dict[str, list[list[tuple[float, float]]]] = {
    "H": [[(0, 0), (0, 6)], [(4, 0), (4, 6)], [(0, 3), (4, 3)]],
    "O": [[(1, 0), (3, 0), (4, 1), (4, 5), (3, 6), (1, 6), (0, 5), (0, 1), (1, 0)]],
    "S": [[(0, 1), (1, 0), (3, 0), (4, 1), (4, 2), (3, 3), (1, 3), (0, 4), (0, 5), (1, 6),
           (3, 6), (4, 5)]],
    "T": [[(0, 6), (4, 6)], [(2, 6), (2, 0)]],
    "D": [[(0, 0), (0, 6), (3, 6), (4, 5), (4, 1), (3, 0), (0, 0)]],
    "L": [[(0, 6), (0, 0), (4, 0)]],
    "I": [[(1, 0), (3, 0)], [(2, 0), (2, 6)], [(1, 6), (3, 6)]],
    "C": [[(4, 1), (3, 0), (1, 0), (0, 1), (0, 5), (1, 6), (3, 6), (4, 5)]],
    "E": [[(4, 0), (0, 0), (0, 6), (4, 6)], [(0, 3), (3, 3)]],
    "0": [[(1, 0), (3, 0), (4, 1), (4, 5), (3, 6), (1, 6), (0, 5), (0, 1), (1, 0)],
          [(0.5, 0.5), (3.5, 5.5)]],
    "2": [[(0, 5), (1, 6), (3, 6), (4, 5), (4, 4), (0, 0), (4, 0)]],
    "6": [[(4, 5), (3, 6), (1, 6), (0, 5), (0, 1), (1, 0), (3, 0), (4, 1), (4, 2), (3, 3),
           (0, 3)]],
    " ": [],
}


def text_outline(text: str, height: float, stroke: float):
    """The text as a shapely (Multi)Polygon, ``height`` mm tall, strokes ``stroke`` mm wide."""
    import shapely

    scale = height / 6.0
    lines = []
    for k, ch in enumerate(text.upper()):
        for stroke_pts in _GLYPHS[ch]:
            pts = (np.asarray(stroke_pts, dtype=float) + np.array([6.0 * k, 0.0])) * scale
            lines.append(shapely.LineString(pts))
    merged = shapely.union_all(shapely.buffer(lines, stroke / 2.0, quad_segs=4,
                                              join_style="mitre", cap_style="square"))
    return shapely.set_precision(merged, 1e-4)


def text_solid(text: str, height: float, stroke: float, depth: float = 0.0):
    """The text extruded ``depth`` mm (default: ``stroke``), as a manifold3d solid."""
    import manifold3d
    import shapely

    outline = text_outline(text, height, stroke)
    contours = []
    for poly in shapely.get_parts(outline):
        contours.append(np.asarray(poly.exterior.coords)[:-1])
        contours.extend(np.asarray(r.coords)[:-1] for r in poly.interiors)
    section = manifold3d.CrossSection(contours, manifold3d.FillRule.EvenOdd)
    return manifold3d.Manifold.extrude(section, depth or stroke)
