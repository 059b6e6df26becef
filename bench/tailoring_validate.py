"""`bench/tailoring.py --validate`: the analysis and the road-aware predictions against
references nobody on the project tuned.

  * closed form: a bar in tension (F/A, F/(AE)) and a cantilever (Timoshenko beam
    theory; the mesh's limit by Richardson extrapolation of two fine meshes, so the
    gap splits into what the mesh adds and what the fully held root adds);
  * an independent solver: CalculiX (``ccx``, Debian's calculix-ccx, GPL: run as a
    program here, never a dependency of the package) on the very same hexahedra,
    supports and nodal loads; skipped when it is not installed;
  * the roads: coupons analysed with their roads resolved on 0.1 mm boxes against
    the same coupons on 0.5 mm boxes whose elasticity comes from the roads' fill and
    direction (and against the rule of mixtures, E times the fill, used before).
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

# C3D8 corner order (bottom face anticlockwise, then top) in the mesh's corner numbers
CCX_ORDER = (0, 1, 3, 2, 4, 5, 7, 6)
E, NU = 2200.0, 0.35


def _box(length: float, width: float, height: float):  # -> trimesh.Trimesh
    import trimesh

    box = trimesh.creation.box((length, width, height))
    box.apply_translation([length / 2, width / 2, height / 2])
    return box


def bar() -> dict:
    """60 x 8 x 5 mm, one end held, 1 kN on the other: stress and strain mid-length."""
    from slicer.fea.field import analyse_arrays
    from slicer.fea.loadcase import parse_load_case

    box = _box(60.0, 8.0, 5.0)
    case = parse_load_case("[[fixed]]\nbox = [[0, 0, 0], [0, 8, 5]]\n[[force]]\n"
                           "box = [[60, 0, 0], [60, 8, 5]]\nnewtons = [1000, 0, 0]\n")
    solution = analyse_arrays(box.vertices, box.faces, case)
    centres = solution.mesh.centres
    middle = np.abs(centres[:, 0] - 30.0) < 10.0
    stress = float(np.mean(solution.stress[middle, 0]))
    points, u = solution.mesh.points, solution.displacement
    ends = [np.abs(points[:, 0] - x) < 1e-6 for x in _planes(points[:, 0], (20.0, 40.0))]
    strain = (u[ends[1], 0].mean() - u[ends[0], 0].mean()) / (
        points[ends[1], 0][0] - points[ends[0], 0][0])
    return {"stress_error": stress / (1000.0 / 40.0) - 1.0,
            "strain_error": strain / (1000.0 / (40.0 * E)) - 1.0}


def _planes(xs: np.ndarray, wanted: tuple[float, ...]) -> list[float]:
    planes = np.unique(np.round(xs, 9))
    return [float(planes[np.argmin(np.abs(planes - w))]) for w in wanted]


def cantilever_case():  # -> (trimesh, LoadCase, theory mm)
    """100 x 10 x 10 mm, the root held, 10 N down at the tip; Timoshenko's deflection."""
    from slicer.fea.loadcase import parse_load_case

    length, side, force = 100.0, 10.0, 10.0
    case = parse_load_case(
        f"[[fixed]]\nbox = [[0, 0, 0], [0, {side}, {side}]]\n"
        f"[[force]]\nbox = [[{length}, 0, 0], [{length}, {side}, {side}]]\n"
        f"newtons = [0, 0, -{force}]\n")
    inertia = side**4 / 12.0
    theory = force * length**3 / (3 * E * inertia) + force * length / (
        5 / 6 * E / (2 * (1 + NU)) * side * side)
    return _box(length, side, side), case, theory


def tip(solution) -> float:
    """Mean downward deflection of the cantilever's tip face, mm."""
    points = solution.mesh.points
    return -float(np.mean(solution.displacement[points[:, 0] > 100.0 - 1e-6, 2]))


def cantilever() -> dict:
    """Default mesh, and 0.625 / 0.5 mm for the h^2 extrapolation of the mesh's limit."""
    from slicer.fea.field import analyse_arrays

    beam, case, theory = cantilever_case()
    tips = {size: tip(analyse_arrays(beam.vertices, beam.faces, case, size))
            for size in (0.0, 0.625, 0.5)}
    # deflection(h) = limit - c h^2 (the trilinear element converges as h^2)
    h1, h2 = 0.625, 0.5
    limit = (tips[h2] * h1**2 - tips[h1] * h2**2) / (h1**2 - h2**2)
    return {"theory_mm": theory, "default_mm": tips[0.0], "limit_mm": limit,
            "default_vs_theory": tips[0.0] / theory - 1.0,
            "default_vs_limit": tips[0.0] / limit - 1.0,
            "limit_vs_theory": limit / theory - 1.0}


def calculix(size: float = 1.25) -> dict | None:
    """The cantilever on the same hexahedra in CalculiX (C3D8, full integration; its
    .dat file prints seven significant figures); None when ``ccx`` is not installed."""
    ccx = shutil.which("ccx")
    if ccx is None:
        return None
    from slicer.fea.field import analyse_arrays
    from slicer.fea.hexmesh import boundary_faces
    from slicer.fea.solve import fixed_nodes, nodal_loads

    beam, case, theory = cantilever_case()
    solution = analyse_arrays(beam.vertices, beam.faces, case, size)
    mesh = solution.mesh
    faces = boundary_faces(mesh)
    held = fixed_nodes(mesh, faces, case)
    loads = nodal_loads(mesh, faces, case)
    lines = ["*NODE"]
    lines += [f"{i + 1}, {p[0]:.12g}, {p[1]:.12g}, {p[2]:.12g}" for i, p in enumerate(mesh.points)]
    lines.append("*ELEMENT, TYPE=C3D8, ELSET=EALL")
    lines += [f"{e + 1}, " + ", ".join(str(int(n[c]) + 1) for c in CCX_ORDER)
              for e, n in enumerate(mesh.nodes)]
    lines += ["*NSET, NSET=NOUT, GENERATE", f"1, {len(mesh.points)}, 1",
              "*MATERIAL, NAME=M", "*ELASTIC", f"{E!r}, {NU!r}",
              "*SOLID SECTION, ELSET=EALL, MATERIAL=M"]
    started = time.perf_counter()
    theirs = _run_ccx(ccx, lines, held, loads, len(mesh.points))
    seconds = time.perf_counter() - started
    ours = solution.displacement
    scale = float(np.abs(ours).max())
    return {"elements": len(mesh.cells), "ccx_seconds": seconds,
            "max_difference": float(np.abs(theirs - ours).max()) / scale,
            "tip_ours_mm": tip(solution),
            "tip_ccx_mm": -float(np.mean(theirs[mesh.points[:, 0] > 100.0 - 1e-6, 2])),
            "theory_mm": theory}


def _ccx_aniso(elasticity: np.ndarray) -> list[str]:
    """CalculiX's 21 constants of ``*ELASTIC, TYPE=ANISO`` (D1111, D1122, D2222, D1133,
    ...) from a Voigt 6 x 6 (xx, yy, zz, yz, xz, xy; engineering shear), 8 a line."""
    voigt = {(1, 1): 0, (2, 2): 1, (3, 3): 2, (2, 3): 3, (1, 3): 4, (1, 2): 5}
    order = [((1, 1), (1, 1)), ((1, 1), (2, 2)), ((2, 2), (2, 2)), ((1, 1), (3, 3)),
             ((2, 2), (3, 3)), ((3, 3), (3, 3)), ((1, 1), (1, 2)), ((2, 2), (1, 2)),
             ((3, 3), (1, 2)), ((1, 2), (1, 2)), ((1, 1), (1, 3)), ((2, 2), (1, 3)),
             ((3, 3), (1, 3)), ((1, 2), (1, 3)), ((1, 3), (1, 3)), ((1, 1), (2, 3)),
             ((2, 2), (2, 3)), ((3, 3), (2, 3)), ((1, 2), (2, 3)), ((1, 3), (2, 3)),
             ((2, 3), (2, 3))]
    values = [f"{elasticity[voigt[a], voigt[b]]:.12g}" for a, b in order]
    return [", ".join(values[i:i + 8]) for i in range(0, 21, 8)]


def calculix_roads() -> dict | None:
    """A road-aware coupon (+-45 at 40 % with a wall, 0.5 mm boxes, each its own
    anisotropic elasticity) in CalculiX, one ``TYPE=ANISO`` material per element;
    None without ``ccx``."""
    ccx = shutil.which("ccx")
    if ccx is None:
        return None
    from slicer.fea.coupon import Coupon, _grid, coupon_case, coupon_roads
    from slicer.fea.hexmesh import boundary_faces, hex_mesh
    from slicer.fea.roadstiff import box_elasticity
    from slicer.fea.solve import analyse, fixed_nodes, nodal_loads

    coupon = Coupon(fill=0.4, wall=True)
    grid = _grid(coupon, 0.5, 0.5)
    mesh = hex_mesh(grid)
    elasticity = box_elasticity(coupon_roads(coupon), grid, np.zeros(3), NU, mesh.cells)
    case = coupon_case(coupon, E, NU)
    solution = analyse(mesh, case, elasticity=elasticity)
    faces = boundary_faces(mesh)
    held = fixed_nodes(mesh, faces, case)
    loads = nodal_loads(mesh, faces, case)
    lines = ["*NODE"]
    lines += [f"{i + 1}, {p[0]:.12g}, {p[1]:.12g}, {p[2]:.12g}" for i, p in enumerate(mesh.points)]
    for e, n in enumerate(mesh.nodes):
        lines.append(f"*ELEMENT, TYPE=C3D8, ELSET=E{e + 1}")
        lines.append(f"{e + 1}, " + ", ".join(str(int(n[c]) + 1) for c in CCX_ORDER))
    lines += ["*NSET, NSET=NOUT, GENERATE", f"1, {len(mesh.points)}, 1"]
    for e in range(len(mesh.cells)):
        lines += [f"*MATERIAL, NAME=M{e + 1}", "*ELASTIC, TYPE=ANISO",
                  *_ccx_aniso(E * elasticity[e]),
                  f"*SOLID SECTION, ELSET=E{e + 1}, MATERIAL=M{e + 1}"]
    theirs = _run_ccx(ccx, lines, held, loads, len(mesh.points))
    ours = solution.displacement
    return {"elements": len(mesh.cells),
            "max_difference": float(np.abs(theirs - ours).max()) / float(np.abs(ours).max())}


def _run_ccx(ccx: str, model: list[str], held: np.ndarray, loads: np.ndarray,
             nodes: int) -> np.ndarray:
    """Run CalculiX on ``model`` (nodes, elements, materials) with one static step: the
    ``held`` nodes fixed in x, y and z, the nodal ``loads``; the displacements (nodes, 3)."""
    lines = [*model, "*STEP", "*STATIC", "*BOUNDARY"]
    lines += [f"{n + 1}, 1, 3" for n in held]
    lines.append("*CLOAD")
    for n, comp in zip(*np.nonzero(np.abs(loads) > 0), strict=True):
        lines.append(f"{n + 1}, {comp + 1}, {loads[n, comp]:.15g}")
    lines += ["*NODE PRINT, NSET=NOUT", "U", "*END STEP"]
    with tempfile.TemporaryDirectory(prefix="bench-ccx-") as tmp:
        (Path(tmp) / "case.inp").write_text("\n".join(lines) + "\n", encoding="ascii")
        subprocess.run([ccx, "-i", "case"], cwd=tmp, capture_output=True, text=True,
                       timeout=1200, check=True, env={"OMP_NUM_THREADS": "1",
                                                      "PATH": "/usr/bin:/bin"})
        return _read_dat(Path(tmp) / "case.dat", nodes)


def _read_dat(path: Path, nodes: int) -> np.ndarray:
    """The displacements (nodes, 3) a ``*NODE PRINT`` wrote to CalculiX's .dat file."""
    out = np.full((nodes, 3), np.nan)
    reading = False
    for line in path.read_text(encoding="ascii", errors="replace").splitlines():
        if "displacements" in line:
            reading = True
            continue
        words = line.split()
        if reading and len(words) == 4:
            out[int(words[0]) - 1] = [float(w) for w in words[1:]]
    return out


def coupons() -> list[dict]:
    """Resolved roads (0.1 mm boxes) against the homogenised boxes and the fill rule."""
    from slicer.fea.coupon import Coupon, fill_modulus, homogenised_modulus, resolved_modulus

    cases = {
        "solid, +-45, wall": Coupon(fill=1.0, wall=True),
        "+-45 at 20 %": Coupon(fill=0.2),
        "+-45 at 40 %": Coupon(fill=0.4),
        "+-45 at 60 %": Coupon(fill=0.6),
        "+-45 at 40 %, wall": Coupon(fill=0.4, wall=True),
        "+-30 at 40 %": Coupon(fill=0.4, angle=30.0),
        "0 (along the pull) at 40 %": Coupon(fill=0.4, angle=0.0),
        "90 (across the pull) at 40 %": Coupon(fill=0.4, angle=90.0),
    }
    rows = []
    for name, coupon in cases.items():
        resolved = resolved_modulus(coupon, E, NU, size=0.1)
        rows.append({"coupon": name, "resolved_mpa": resolved,
                     "homogenised_mpa": homogenised_modulus(coupon, E, NU),
                     "fill_rule_mpa": fill_modulus(coupon, E, NU)})
    return rows


def validate(gcodes: Path | None = None) -> dict:
    """Every comparison, printed as it comes; the figures as a dict. ``gcodes``: the
    output folder of ``hostd tailor examples/dogbone`` whose prints' gages are also
    compared (slow: about a million unknowns each when resolved)."""
    figures: dict = {}
    figures["bar"] = row = bar()
    print(f"bar 60 x 8 x 5 mm, 1 kN: stress vs F/A {100 * row['stress_error']:+.3f} %, "
          f"strain vs F/(AE) {100 * row['strain_error']:+.3f} %")
    figures["cantilever"] = row = cantilever()
    print(f"cantilever 100 x 10 x 10 mm, 10 N: Timoshenko {row['theory_mm']:.4f} mm; default "
          f"mesh {row['default_mm']:.4f} mm ({100 * row['default_vs_theory']:+.2f} %); "
          f"the mesh's limit (h^2 from 0.625 and 0.5 mm) {row['limit_mm']:.4f} mm "
          f"({100 * row['limit_vs_theory']:+.2f} %: the fully held root); default vs that "
          f"limit {100 * row['default_vs_limit']:+.2f} % (the mesh)")
    row = calculix()
    figures["calculix"] = row
    if row is None:
        print("CalculiX: ccx not installed (apt-get install calculix-ccx): skipped")
    else:
        print(f"CalculiX on the same {row['elements']} hexahedra (cantilever at 1.25 mm): "
              f"largest displacement difference {row['max_difference']:.2e} of the largest "
              f"displacement; tip {row['tip_ours_mm']:.6f} mm here, {row['tip_ccx_mm']:.6f} mm "
              f"in ccx ({row['ccx_seconds']:.1f} s)")
    row = calculix_roads()
    figures["calculix_roads"] = row
    if row is not None:
        print(f"CalculiX on a road-aware coupon ({row['elements']} boxes, each its own "
              f"anisotropic elasticity): largest displacement difference "
              f"{row['max_difference']:.2e} of the largest displacement")
    print("coupons 16 x 6 x 0.8 mm (4 layers of 0.2 mm, 0.45 mm roads, 3 mm solid tabs), "
          "pulled along x; modulus MPa:")
    print(f"  {'coupon':30s} {'resolved':>9s} {'road-aware':>11s} {'error':>7s} "
          f"{'fill rule':>10s} {'error':>7s}")
    figures["coupons"] = rows = coupons()
    for r in rows:
        ours = 100 * (r["homogenised_mpa"] / r["resolved_mpa"] - 1)
        rule = 100 * (r["fill_rule_mpa"] / r["resolved_mpa"] - 1)
        print(f"  {r['coupon']:30s} {r['resolved_mpa']:9.0f} {r['homogenised_mpa']:11.0f} "
              f"{ours:+6.1f}% {r['fill_rule_mpa']:10.0f} {rule:+6.0f}%")
    if gcodes is not None:
        print(f"the dogbone's gage (x 40..60 of each print in {gcodes}) cut out and pulled; "
              "modulus MPa:")
        figures["dogbone_gage"] = dogbone_gage(gcodes)
    return figures


def dogbone_gage(out: Path, size: float = 0.125, size_z: float = 0.2,
                 names: tuple[str, ...] = ("linear", "stress-a", "stress-b", "stress-optimal"),
                 ) -> list[dict]:
    """The dogbone's gage (x 40..60, the 10 mm narrow section, whole thickness) cut out of
    each print of ``out`` (``hostd tailor examples/dogbone -o OUT``), held at x = 40,
    pulled at x = 60, read over its middle third: its roads resolved on ``size`` mm boxes (one
    per layer in z, or ``size_z``) against the road-aware 0.5 mm boxes and the fill rule.
    At 0.125 mm and a box per layer the resolved roads are themselves too stiff (a
    coupon: 25 % over its 0.1 mm, half-a-layer value)."""
    import tomllib

    from slicer.fea.coupon import Coupon, coupon_case, gage_modulus
    from slicer.fea.hexmesh import hex_mesh
    from slicer.fea.printed import fill_fractions, modulus_scale, read_roads
    from slicer.fea.roadstiff import box_elasticity
    from slicer.fea.solve import analyse
    from slicer.fea.voxel import VoxelGrid
    from slicer.input.mesh import read_stl
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    folder = Path(__file__).resolve().parents[1] / "examples" / "dogbone"
    vertices, _ = read_stl(folder / "dogbone.stl")
    settings = SliceSettings.from_mapping(tomllib.loads((folder / "dogbone.toml").read_text()))
    bounds = SlicePlan.from_file(folder / "dogbone.stl", settings, (220.0, 220.0, 250.0)).bounds
    shift = np.array([vertices[:, 0].min() - bounds[0], vertices[:, 1].min() - bounds[1],
                      vertices[:, 2].min()])
    shift = shift - np.array([40.0, 10.0, 0.0])  # the piece's own frame: x 0..20, y 0..10
    # the piece as a coupon whose "tabs" are the 5 mm outside the extensometer's 10 mm
    piece = Coupon(length=20.0, width=10.0, layers=25, height=0.2, tab=0.0)
    case = coupon_case(piece, E, NU)

    def grid(cell_xy: float, cell_z: float) -> VoxelGrid:
        extent = np.array([20.0, 10.0, 5.0])
        shape = np.rint(extent / np.array([cell_xy, cell_xy, cell_z])).astype(int)
        return VoxelGrid(np.zeros(3), extent / shape, np.ones(tuple(shape), dtype=bool))

    rows = []
    for name in names:
        path = out / f"{name}.gcode"
        if not path.is_file():
            continue
        roads = read_roads(path.read_text(encoding="ascii").splitlines(),
                           settings.filament_diameter)
        row = {"print": name}
        for label, cells, how in (("resolved", (size, size_z), "scale"),
                                  ("homogenised", (0.5, 0.5), "roads"),
                                  ("fill_rule", (0.5, 0.5), "scale")):
            g = grid(*cells)
            mesh = hex_mesh(g)
            if how == "roads":
                solution = analyse(mesh, case, elasticity=box_elasticity(
                    roads, g, shift, NU, mesh.cells))
            else:
                fractions = fill_fractions(roads, g, shift)
                solution = analyse(mesh, case, modulus_scale(fractions, mesh.cells))
            row[f"{label}_mpa"] = gage_modulus(mesh.points, solution.displacement, piece, 100.0)
        rows.append(row)
        print(f"  {name:15s} resolved {row['resolved_mpa']:6.0f}  road-aware "
              f"{row['homogenised_mpa']:6.0f} "
              f"({100 * (row['homogenised_mpa'] / row['resolved_mpa'] - 1):+.1f} %)  fill rule "
              f"{row['fill_rule_mpa']:6.0f} "
              f"({100 * (row['fill_rule_mpa'] / row['resolved_mpa'] - 1):+.0f} %)", flush=True)
    return rows
