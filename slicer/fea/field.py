"""The analysis of a model file as a stress field file the slicer reads, cached by its inputs."""

from __future__ import annotations

import hashlib
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from slicer.fea.hexmesh import CORNERS, HexMesh, boundary_faces, hex_mesh
from slicer.fea.loadcase import (
    ABS_POISSON,
    ABS_YOUNGS_MPA,
    LoadCase,
    LoadCaseError,
    read_load_case,
)
from slicer.fea.optimal import ITERATIONS, OBJECTIVE_VERSION, optimal_density
from slicer.fea.solve import Solution, analyse, fixed_nodes, nodal_loads
from slicer.fea.voxel import default_cell, mesh_volume, voxelize
from slicer.fields.stress import SCALE_PERCENTILE

FIELD_VERSION = "2"  # bump when the analysis changes what it writes


@dataclass(frozen=True)
class FieldFile:
    """A stress field written for the slicer: ``path`` (NPZ with ``points`` (n, 3) and
    ``values`` (n,), von Mises MPa on the lattice of the mesh's nodes); ``cached``
    True when it was found ready; ``peak_mpa`` the largest element von Mises stress;
    ``cell`` (3,) mm the mesh's box edges; ``elements`` their count; ``seconds``
    the analysis took (0 when cached)."""

    path: Path
    cached: bool
    peak_mpa: float
    cell: tuple[float, float, float]
    elements: int
    seconds: float


def nodal_lattice(solution: Solution, values: np.ndarray | None = None) -> np.ndarray:
    """Element values (e,) (default: von Mises) averaged to the lattice's nodes:
    (nx+1, ny+1, nz+1) float64. Nodes of no solid element take the nearest
    node's value, so the field is defined on the whole box."""
    mesh = solution.mesh
    values = solution.von_mises if values is None else np.asarray(values, dtype=float)
    shape = np.array(mesh.grid.solid.shape) + 1
    total = np.zeros(int(np.prod(shape)))
    count = np.zeros(int(np.prod(shape)))
    for offset in CORNERS:
        flat = np.ravel_multi_index(tuple((mesh.cells + offset).T), shape)
        total += np.bincount(flat, weights=values, minlength=len(total))
        count += np.bincount(flat, minlength=len(count))
    known = (count > 0).reshape(shape)
    lattice = np.where(count > 0, total / np.maximum(count, 1), 0.0).reshape(shape)
    if not known.all():
        index = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
        lattice = lattice[tuple(index)]
    return lattice


def lattice_points(solution: Solution) -> np.ndarray:
    """Positions (n, 3) float64 mm of every lattice node, in the order of
    ``nodal_lattice(...).ravel()``, in the model's own frame."""
    grid = solution.mesh.grid
    axes = [grid.origin[k] + grid.cell[k] * np.arange(grid.solid.shape[k] + 1) for k in range(3)]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([m.ravel() for m in mesh])


def mesh_arrays(
    vertices: np.ndarray, faces: np.ndarray, case: LoadCase, size: float = 0.0
) -> HexMesh:
    """The hexahedra of the mesh's voxels (``size`` mm boxes, 0 for the default)."""
    size = size or default_cell(mesh_volume(vertices, faces))
    try:
        grid = voxelize(vertices, faces, size)
    except ValueError as exc:
        raise LoadCaseError(f"{case.source}: {exc}") from exc
    if not grid.solid.any():
        raise LoadCaseError(f"{case.source}: the model has no inside at a {size:g} mm mesh")
    return hex_mesh(grid)


def analyse_arrays(
    vertices: np.ndarray, faces: np.ndarray, case: LoadCase, size: float = 0.0
) -> Solution:
    """Voxelise the mesh (``size`` mm boxes, 0 for the default) and solve the case."""
    return analyse(mesh_arrays(vertices, faces, case, size), case)


def check_case(
    model: str | os.PathLike[str],
    load: str | os.PathLike[str],
    size: float = 0.0,
    youngs: float = ABS_YOUNGS_MPA,
    poisson: float = ABS_POISSON,
) -> LoadCase:
    """Everything :func:`stress_field_file` would refuse, without solving: the file's
    keys and values, then every region against the meshed model (a region that
    selects no face, a body held by nothing). Cheap enough to run when a job is
    taken. Raises LoadCaseError; a model that cannot be read raises ModelError."""
    from slicer.input.mesh import read_stl

    model, load = Path(model), Path(load)
    if not model.is_file():
        raise LoadCaseError(f"{load.name}: its model {model.name} is missing")
    case = read_load_case(load, youngs, poisson)
    vertices, faces = read_stl(model)
    size = size or default_cell(mesh_volume(vertices, faces))
    try:
        grid = voxelize(vertices, faces, size)
    except ValueError as exc:
        raise LoadCaseError(f"{case.source}: {exc}") from exc
    mesh = hex_mesh(grid)
    surface = boundary_faces(mesh)
    fixed_nodes(mesh, surface, case)
    nodal_loads(mesh, surface, case)
    return case


def field_key(vertices: np.ndarray, faces: np.ndarray, case: LoadCase, size: float,
              optimal: float = 0.0) -> str:
    """The cache key of an analysis: the model's mesh as read (``vertices`` (v, 3),
    ``faces`` (f, 3)), the load case, material and size (and, for an optimised
    density, its mean)."""
    digest = hashlib.sha256()
    if optimal:
        digest.update(f"optimal {optimal!r} {ITERATIONS} {OBJECTIVE_VERSION}".encode())
    digest.update(FIELD_VERSION.encode())
    mesh = hashlib.sha256(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    mesh.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    digest.update(mesh.digest())
    digest.update(case.key().encode())
    digest.update(repr(float(size)).encode())
    return digest.hexdigest()[:32]


def write_field(path: Path, solution: Solution, values: np.ndarray | None = None) -> None:
    """Write the nodal von Mises lattice (or other element ``values`` (e,)) as an NPZ the
    stress field reads (atomically)."""
    values = solution.von_mises if values is None else values
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".fea-", suffix=".npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(
                handle,
                points=lattice_points(solution),
                values=nodal_lattice(solution, values).ravel(),
                peak=np.float64(values.max()),
                scale=np.float64(np.percentile(values, SCALE_PERCENTILE)),
                cell=solution.mesh.grid.cell,
                elements=np.int64(len(solution.mesh.cells)),
            )
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def field_path(
    model: str | os.PathLike[str],
    load: str | os.PathLike[str],
    cache_dir: str | os.PathLike[str],
    size: float = 0.0,
    youngs: float = ABS_YOUNGS_MPA,
    poisson: float = ABS_POISSON,
    optimal: float = 0.0,
) -> tuple[Path, LoadCase, np.ndarray, np.ndarray, float]:
    """Where the analysis of ``model`` under ``load`` is cached (see :func:`field_key`),
    with the case, the model's vertices and faces and the mesh size it uses.
    ``optimal`` > 0: the optimised density of that mean instead of the stress."""
    from slicer.input.mesh import read_stl

    model, load = Path(model), Path(load)
    if not model.is_file():
        raise LoadCaseError(f"{load.name}: its model {model.name} is missing")
    case = read_load_case(load, youngs, poisson)
    vertices, faces = read_stl(model)
    size = size or default_cell(mesh_volume(vertices, faces))
    kind = "optimal" if optimal else "stress"
    key = field_key(vertices, faces, case, size, optimal)  # the file is read once, here
    path = Path(cache_dir) / f"{kind}-{key}.npz"
    return path, case, vertices, faces, size


def read_field_file(path: Path) -> FieldFile:
    """The facts of a field file already written (``cached`` True)."""
    with np.load(path) as data:
        return FieldFile(path, True, float(data["peak"]), tuple(data["cell"]),
                         int(data["elements"]), 0.0)


def solve_field(path: Path, case: LoadCase, vertices: np.ndarray, faces: np.ndarray,
                size: float, optimal: float = 0.0) -> FieldFile:
    """Analyse and write the field file ``path``: the von Mises stress, or with
    ``optimal`` > 0 the density of that mean that :func:`optimal_density` finds."""
    started = time.perf_counter()
    mesh = mesh_arrays(vertices, faces, case, size)
    solution = analyse(mesh, case)
    values = solution.von_mises
    if optimal:
        values, _ = optimal_density(mesh, case, optimal)
    write_field(path, solution, values)
    cx, cy, cz = (float(c) for c in mesh.grid.cell)
    return FieldFile(path, False, float(values.max()), (cx, cy, cz),
                     len(mesh.cells), time.perf_counter() - started)


def stress_field_file(
    model: str | os.PathLike[str],
    load: str | os.PathLike[str],
    cache_dir: str | os.PathLike[str],
    size: float = 0.0,
    youngs: float = ABS_YOUNGS_MPA,
    poisson: float = ABS_POISSON,
    optimal: float = 0.0,
) -> FieldFile:
    """The von Mises field (or with ``optimal`` > 0 the optimised density of that mean,
    see :mod:`slicer.fea.optimal`) of ``model`` (STL) under the load case file ``load``, as a
    field file in ``cache_dir`` named by :func:`field_key`; analysed only when no
    such file exists yet. ``youngs`` (MPa) and ``poisson`` are the material unless
    the case names its own. Raises LoadCaseError (bad case, model missing) or
    slicer.errors.ModelError (unreadable STL)."""
    path, case, vertices, faces, size = field_path(model, load, cache_dir, size, youngs, poisson,
                                                   optimal)
    if path.is_file():
        return read_field_file(path)
    return solve_field(path, case, vertices, faces, size, optimal)
