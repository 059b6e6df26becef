"""A corpus of parametric test models, generated deterministically into ``bench/.cache/corpus``.

Each model is a small function of fixed parameters (solids from manifold3d, the
gyroid ball from scikit-image's marching cubes, defects added by plain numpy),
written as binary STL (or ASCII where the format is the point). The same run
writes the same bytes, and no network is needed.

Usage (from the repository root), to write them all and list them:
    .venv/bin/python bench/corpus.py [--out DIR] [--force]
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.peers import CACHE
from bench.stlfiles import large_model, write_ascii, write_binary  # noqa: F401 (re-exported)

CORPUS = CACHE / "corpus"
# bump when a model's recipe changes, so cached files are rewritten
VERSION = 3

Mesh = tuple[np.ndarray, np.ndarray]  # vertices (v, 3) float64 mm, faces (f, 3) int64


def _m():
    import manifold3d

    return manifold3d


def box(x: float, y: float, z: float, at: tuple[float, float, float] = (0, 0, 0)):
    """A box with its minimum corner at ``at``."""
    return _m().Manifold.cube((x, y, z)).translate(at)


def cyl(r: float, h: float, at: tuple[float, float, float] = (0, 0, 0), seg: int = 48):
    """An upright cylinder of radius ``r`` standing on ``at``."""
    return _m().Manifold.cylinder(h, r, -1.0, seg).translate(at)


def prism(points: list[tuple[float, float]], h: float, at=(0, 0, 0), twist=0.0, div=0):
    """The polygon ``points`` (x, y) extruded ``h`` up from ``at``."""
    m = _m()
    section = m.CrossSection([np.asarray(points, dtype=float)], m.FillRule.EvenOdd)
    return m.Manifold.extrude(section, h, div, twist).translate(at)


def union(parts):
    """Boolean union of manifolds."""
    return _m().Manifold.batch_boolean(list(parts), _m().OpType.Add)


def mesh_of(solid) -> Mesh:
    """Vertices and faces of a manifold."""
    out = solid.to_mesh()
    return np.asarray(out.vert_properties)[:, :3].astype(np.float64), np.asarray(
        out.tri_verts, dtype=np.int64
    )


# ---- plates, holes, bosses, ribs, thin walls ------------------------------
def plate_holes_slots():
    """80 x 50 x 5 mm plate, six holes of 3-8 mm and two slots."""
    solid = box(80, 50, 5)
    for k, r in enumerate((1.5, 2, 2.5, 3, 3.5, 4)):
        solid -= cyl(r, 7, (10 + 12 * k, 12, -1))
    for y in (30, 40):
        solid -= union([box(30, 4, 7, (20, y - 2, -1)), cyl(2, 7, (20, y, -1)),
                        cyl(2, 7, (50, y, -1))])
    return solid


def bosses():
    """A plate with six hollow bosses of different heights."""
    solid = box(70, 45, 3)
    for k in range(6):
        x, y = 12 + 23 * (k % 3), 12 + 21 * (k // 3)
        solid += cyl(5, 8 + 3 * k, (x, y, 0)) - cyl(1.6, 30, (x, y, 1))
    return solid


def ribbed_plate():
    """A plate with 1.2 mm ribs one way and 2 mm ribs across."""
    parts = [box(90, 60, 3)]
    parts += [box(1.2, 60, 12, (8 + 12 * k, 0, 3)) for k in range(7)]
    parts += [box(90, 2, 8, (0, 14 + 16 * k, 3)) for k in range(3)]
    return union(parts)


def thin_walls():
    """Walls 0.6, 0.8, 1.0, 1.2, 1.5 and 2.0 mm thick, 25 mm tall, on a base."""
    parts = [box(70, 30, 2)]
    widths = (0.6, 0.8, 1.0, 1.2, 1.5, 2)
    parts += [box(t, 26, 25, (5 + 11 * k, 2, 2)) for k, t in enumerate(widths)]
    return union(parts)


def thin_ring_walls():
    """Concentric round walls 0.6-2 mm thick, 15 mm tall."""
    parts = []
    r = 4.0
    for t in (0.6, 0.8, 1.0, 1.2, 1.5, 2.0):
        parts.append(cyl(r + t, 15, seg=96) - cyl(r, 17, (0, 0, -1), seg=96))
        r += t + 3.0
    return union([*parts, cyl(r, 1.0, seg=96)])


def enclosure():
    """An open box, 1.6 mm walls, with screw posts and a lip."""
    solid = box(60, 40, 25) - box(56.8, 36.8, 30, (1.6, 1.6, 1.6))
    for x, y in ((5, 5), (55, 5), (5, 35), (55, 35)):
        solid += cyl(3, 25, (x, y, 0)) - cyl(1.2, 30, (x, y, 3))
    return solid + (box(60, 40, 2, (0, 0, 25)) - box(58, 38, 4, (1, 1, 24)))


def honeycomb():
    """A 5 mm plate with hexagonal holes (1.2 mm webs)."""
    solid = box(80, 60, 5)
    hexagon = [(3.5 * np.cos(a), 3.5 * np.sin(a)) for a in np.arange(6) * np.pi / 3]
    for i in range(10):
        for j in range(9):
            x, y = 6 + 7.2 * i + (3.6 if j % 2 else 0), 6 + 6.2 * j
            if x < 76 and y < 56:
                solid -= prism([(x + px, y + py) for px, py in hexagon], 7, (0, 0, -1))
    return solid


def gear():
    """A 24-tooth spur gear, 8 mm thick, with a keyed bore."""
    angles = np.linspace(0, 2 * np.pi, 24 * 8, endpoint=False)
    radius = 30 + 2.5 * np.clip(3 * np.sin(24 * angles), -1, 1)
    outline = list(zip(radius * np.cos(angles), radius * np.sin(angles), strict=True))
    return prism(outline, 8) - cyl(5, 10, (0, 0, -1)) - box(2, 3, 10, (-1, 4, -1))


# ---- overhangs, bridges, towers --------------------------------------------
def overhang_bridge():
    """Two pillars joined by a 40 mm bridge, a 45 degree ramp and a 60 degree ledge."""
    parts = [box(8, 20, 20), box(8, 20, 20, (48, 0, 0)), box(56, 20, 3, (0, 0, 20))]
    parts.append(prism([(0, 0), (15, 0), (15, 15)], 20, (0, 0, 0)).rotate((90, 0, 0))
                 .translate((56, 20, 0)))
    parts.append(prism([(0, 0), (6, 10), (0, 10)], 20).rotate((90, 0, 0)).translate((-6, 20, 13)))
    return union(parts)


def cone_sphere_overhangs():
    """An upside-down cone and a sphere on a pin: every overhang angle."""
    m = _m()
    cone = m.Manifold.cylinder(20, 2, 15, 96).translate((0, 0, 0))
    ball = m.Manifold.sphere(10, 96).translate((35, 0, 12)) + cyl(2, 3, (35, 0, 0))
    return cone + ball


def tall_tower():
    """A 6 x 6 x 90 mm tower with a 3 mm hole: many small layers."""
    return box(6, 6, 90) - cyl(1.5, 100, (3, 3, -1))


def pins():
    """Round pins 0.8-3 mm in diameter, 20 mm tall, on a base."""
    parts = [box(60, 20, 1.5)]
    for k, d in enumerate((0.8, 1.0, 1.2, 1.6, 2.0, 2.5, 3.0)):
        parts.append(cyl(d / 2, 20, (5 + 8 * k, 10, 1.5), seg=32))
    return union(parts)


# ---- several bodies ----------------------------------------------------------
def plate_five_bodies():
    """Five separate bodies on one plate (box, cylinder, wedge, ring, cross)."""
    return union([
        box(15, 15, 10, (0, 0, 0)), cyl(8, 12, (35, 8, 0)),
        prism([(0, 0), (18, 0), (0, 12)], 14, (55, 0, 0)),
        cyl(9, 6, (12, 40, 0)) - cyl(6, 8, (12, 40, -1)),
        union([box(20, 5, 8, (30, 37.5, 0)), box(5, 20, 8, (37.5, 30, 0))]),
    ])


def grid_of_parts():
    """Sixteen small parts in a grid (8 cubes, 8 cylinders)."""
    parts = []
    for k in range(16):
        x, y = 14 * (k % 4), 14 * (k // 4)
        parts.append(box(8, 8, 6 + k % 5, (x, y, 0)) if k % 2
                     else cyl(4, 5 + k % 7, (x + 4, y + 4, 0)))
    return union(parts)


# ---- lattices ----------------------------------------------------------------
def lattice_cubic():
    """A 40 mm cubic strut lattice, 1.6 mm struts every 8 mm."""
    parts = []
    for i in range(6):
        for j in range(6):
            a, b = i * 8.0 - 0.8, j * 8.0 - 0.8
            parts.append(box(1.6, 1.6, 41.6, (a + 0.8, b + 0.8, 0)))
            parts.append(box(41.6, 1.6, 1.6, (0, a + 0.8, b + 0.8)))
            parts.append(box(1.6, 41.6, 1.6, (a + 0.8, 0, b + 0.8)))
    return union(parts)


def lattice_diagonal():
    """A 30 mm body-centred lattice of round struts (every overhang angle)."""
    m = _m()
    strut = m.Manifold.cylinder(1.0, 0.6, -1, 12, True)
    parts = [box(32, 32, 1.2)]
    corners = np.array([(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * 10
    for cell in np.ndindex(3, 3, 3):
        origin = np.array(cell, float) * 10 + (1, 1, 1.2)
        centre = origin + 5
        for c in corners:
            v = c + origin - centre
            length = float(np.linalg.norm(v))
            tilt = np.degrees(np.arccos(v[2] / length))
            turn = np.degrees(np.arctan2(v[1], v[0]))
            parts.append(strut.scale((1, 1, length)).rotate((0, tilt, turn))
                         .translate(tuple(centre + v / 2)))
    return union(parts)


# ---- vases and curved shells ---------------------------------------------------
def vase_round():
    """A round vase, 0.8 mm wall, 1.2 mm bottom, 60 mm tall, flaring."""
    outer = _m().Manifold.cylinder(60, 20, 28, 128)
    return outer - _m().Manifold.cylinder(60, 19.2, 27.2, 128).translate((0, 0, 1.2))


def vase_twisted():
    """A star vase with 1.2 mm walls, twisted 90 degrees over 80 mm."""
    a = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    r = 22 + 4 * np.cos(6 * a)
    outer = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    inner = np.stack([(r - 1.2) * np.cos(a), (r - 1.2) * np.sin(a)], axis=1)
    m = _m()
    shell = m.Manifold.extrude(m.CrossSection([outer, inner[::-1]], m.FillRule.EvenOdd),
                               80, 70, 90.0)
    return shell + m.Manifold.extrude(m.CrossSection([outer]), 1.2)


def torus_knotish():
    """A torus and a sphere shell: smooth, curved, many small faces."""
    m = _m()
    torus = m.Manifold.revolve(m.CrossSection.circle(6, 64).translate((20, 0)), 128)
    shell = m.Manifold.sphere(12, 128) - m.Manifold.sphere(10.5, 128)
    shell = shell.trim_by_plane((0, 0, 1), -6).translate((0, 0, 6 + 12))
    return torus.translate((0, 0, 6)) + shell.translate((45, 0, -12))


def gyroid_ball() -> Mesh:
    """A 50 mm ball of gyroid sheet (0.8 mm thick, 6 mm period), by marching cubes."""
    from skimage.measure import marching_cubes

    step = 0.6
    axis = np.arange(-26.0, 26.0 + step / 2, step)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij", sparse=True)
    k = 2 * np.pi / 6.0
    g = (np.sin(k * x) * np.cos(k * y) + np.sin(k * y) * np.cos(k * z)
         + np.sin(k * z) * np.cos(k * x))
    field = np.maximum(np.abs(g) / k - 0.4, np.sqrt(x * x + y * y + z * z) - 25.0)
    field = field.astype(np.float32)
    verts, faces, _, _ = marching_cubes(field, 0.0, spacing=(step, step, step))
    return verts.astype(np.float64), faces.astype(np.int64)


# ---- the bracket, and meshes that need repair ------------------------------------
def bracket_solid():
    """An L-bracket: holes, a slot, a counterbore, 1.2 mm ribs, a bridge, a 45 degree overhang."""
    base = box(70, 40, 6)
    base -= cyl(2.2, 10, (10, 10, -1)) + cyl(2.2, 10, (60, 10, -1))
    base -= union([box(16, 4.4, 10, (27, 8, -1)), cyl(2.2, 10, (27, 10.2, -1)),
                   cyl(2.2, 10, (43, 10.2, -1))])
    base -= cyl(3.4, 10, (35, 28, -1)) + cyl(5.5, 10, (35, 28, 3))  # counterbore
    wall = box(70, 6, 40, (0, 34, 0))
    wall -= box(20, 10, 12, (25, 32, 6))  # a window: its top is a 20 mm bridge
    wall -= _m().Manifold.cylinder(10, 3, -1, 48).rotate((90, 0, 0)).translate((12, 42, 28))
    ribs = [_yz(prism([(0, 0), (28, 0), (0, 34)], 1.2), x + 1.2, 34, 6) for x in (4, 64.8)]
    ledge = _yz(prism([(0, 0), (10, 10), (0, 10)], 30), 50, 34, 20)  # 45 degree underside
    return union([base, wall, *ribs, ledge])


def _yz(solid, x: float, y: float, z: float):
    """A solid drawn in (u, v, w) turned so u runs along -y, v up and w along -x, then moved."""
    return solid.transform(np.array([[0, 0, -1, x], [-1, 0, 0, y], [0, 1, 0, z]], float))


def flip_some(mesh: Mesh, fraction: float, seed: int) -> Mesh:
    """The mesh with a random ``fraction`` of its faces wound the other way (fixed seed)."""
    v, f = mesh
    rng = np.random.default_rng(seed)
    flip = rng.random(len(f)) < fraction
    f = f.copy()
    f[flip] = f[flip][:, ::-1]
    return v, f


def bracket_bad_winding() -> Mesh:
    """The bracket exported with a third of its faces wound the wrong way."""
    return flip_some(mesh_of(bracket_solid()), 0.33, 16)


def inverted_normals() -> Mesh:
    """A holed block with every face wound inwards."""
    v, f = mesh_of(box(30, 20, 15) - cyl(5, 20, (15, 10, -1)))
    return v, f[:, ::-1].copy()


def inconsistent_cylinder() -> Mesh:
    """A fine cylinder with half its faces flipped."""
    return flip_some(mesh_of(cyl(15, 30, seg=256)), 0.5, 3)


def mesh_with_holes() -> Mesh:
    """A sphere with twelve faces missing (small triangular holes)."""
    v, f = mesh_of(_m().Manifold.sphere(15, 96).translate((0, 0, 15)))
    rng = np.random.default_rng(7)
    drop = rng.choice(len(f), 12, replace=False)
    return v, np.delete(f, drop, axis=0)


def duplicates_and_slivers() -> Mesh:
    """A gear with every tenth face written twice and degenerate faces added."""
    v, f = mesh_of(gear())
    extra = f[::10]
    slivers = np.stack([f[::15, 0], f[::15, 0], f[::15, 1]], axis=1)
    return v, np.concatenate([f, extra, slivers])


def cubes_sharing_edge() -> Mesh:
    """Two 20 mm cubes touching along one edge (a non-manifold edge), as two shells."""
    a = mesh_of(box(20, 20, 20))
    b = mesh_of(box(20, 20, 20, (20, 20, 0)))
    return np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1] + len(a[0])])


def overlapping_boxes() -> Mesh:
    """Two boxes overlapping by 10 mm, written as two separate shells."""
    a = mesh_of(box(30, 20, 15))
    b = mesh_of(box(30, 20, 25, (20, 5, 0)))
    return np.concatenate([a[0], b[0]]), np.concatenate([a[1], b[1] + len(a[0])])


def _solid(fn: Callable) -> Callable[[], Mesh]:
    return lambda: mesh_of(fn())


# name -> (mesh maker, writer kind)
MODELS: dict[str, tuple[Callable[[], Mesh], str]] = {
    "plate_holes_slots": (_solid(plate_holes_slots), "binary"),
    "bosses": (_solid(bosses), "binary"),
    "ribbed_plate": (_solid(ribbed_plate), "binary"),
    "thin_walls": (_solid(thin_walls), "binary"),
    "thin_ring_walls": (_solid(thin_ring_walls), "binary"),
    "enclosure": (_solid(enclosure), "binary"),
    "honeycomb": (_solid(honeycomb), "binary"),
    "gear": (_solid(gear), "binary"),
    "text_plate": (lambda: mesh_of(_text_plate()), "binary"),
    "text_standing": (lambda: mesh_of(_text_standing()), "binary"),
    "overhang_bridge": (_solid(overhang_bridge), "binary"),
    "cone_sphere": (_solid(cone_sphere_overhangs), "binary"),
    "tall_tower": (_solid(tall_tower), "binary"),
    "pins": (_solid(pins), "binary"),
    "plate_five_bodies": (_solid(plate_five_bodies), "binary"),
    "grid_of_parts": (_solid(grid_of_parts), "binary"),
    "lattice_cubic": (_solid(lattice_cubic), "binary"),
    "lattice_diagonal": (_solid(lattice_diagonal), "binary"),
    "vase_round": (_solid(vase_round), "binary"),
    "vase_twisted": (_solid(vase_twisted), "binary"),
    "torus_shell": (_solid(torus_knotish), "binary"),
    "gyroid_ball": (gyroid_ball, "binary"),
    "bracket_bad_winding": (bracket_bad_winding, "binary"),
    "inverted_normals": (inverted_normals, "binary"),
    "inconsistent_cylinder": (inconsistent_cylinder, "binary"),
    "mesh_with_holes": (mesh_with_holes, "binary"),
    "duplicates_slivers": (duplicates_and_slivers, "binary"),
    "cubes_sharing_edge": (cubes_sharing_edge, "binary"),
    "overlapping_boxes": (overlapping_boxes, "binary"),
    "ascii_no_endsolid": (_solid(lambda: box(20, 20, 10) - cyl(4, 12, (10, 10, -1))), "ascii-open"),
}


def _text_plate():
    from bench.glyphs import text_solid

    return box(86, 22, 2) + text_solid("HOSTD 2026", 8.0, 1.2).translate((4, 5, 2))


def _text_standing():
    from bench.glyphs import text_solid

    return text_solid("SLICE", 20.0, 3.0).rotate((90, 0, 0)).translate((0, 6, 0)) + box(
        70, 12, 1.5, (-2, -3, 0))


def build(out: Path = CORPUS, force: bool = False, names: list[str] | None = None) -> list[Path]:
    """Write the corpus models (those missing, or all with ``force``); their paths, in order."""
    out.mkdir(parents=True, exist_ok=True)
    stamp = out / "VERSION"
    if not stamp.exists() or stamp.read_text().strip() != str(VERSION):
        force = True
    paths = []
    for name, (make, kind) in MODELS.items():
        if names and name not in names:
            continue
        path = out / f"{name}.stl"
        if force or not path.exists():
            mesh = make()
            tmp = path.with_suffix(".tmp")
            if kind == "binary":
                write_binary(tmp, mesh)
            else:
                write_ascii(tmp, mesh, endsolid=kind != "ascii-open")
            tmp.replace(path)
        paths.append(path)
    if not names:
        stamp.write_text(f"{VERSION}\n")
    return paths


def main(argv: list[str] | None = None) -> int:
    """Write the corpus and print one line per model."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=CORPUS)
    p.add_argument("--force", action="store_true", help="rewrite every model")
    p.add_argument("--models", default="", help="comma-separated names (default: all)")
    args = p.parse_args(argv)
    names = [s for s in args.models.split(",") if s] or None
    for path in build(args.out, args.force, names):
        print(f"{path.stem:24s} {path.stat().st_size:>11,d} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())

