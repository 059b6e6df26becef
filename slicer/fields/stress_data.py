"""Scalar field samples (x, y, z, value) read from CSV, NPZ or VTU, and interpolated in 3D."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slicer.settings import SettingsError

KEY = "infill.file"

SCALAR_NAMES = ("von_mises", "vonmises", "von mises", "sigma_vm", "stress", "value")


class StressData:
    """Samples of a scalar field at scattered points, with linear interpolation between them
    and the nearest sample outside their hull. Samples on a full regular lattice (a
    voxel export) are read with (tri)linear interpolation on the lattice instead,
    clamped at its faces.

    ``points`` (n, 3) float64 mm in the model's own frame; ``values`` (n,) float64.
    Points all at one height are treated as a 2D field that holds for every layer.
    """

    def __init__(self, points: np.ndarray, values: np.ndarray) -> None:
        points = np.asarray(points, dtype=float)
        values = np.asarray(values, dtype=float)
        ok = np.all(np.isfinite(points), axis=1) & np.isfinite(values)
        points, values = points[ok], values[ok]
        if points.shape[0] < 3:
            raise SettingsError(KEY, "fewer than 3 usable samples in the field file")
        self.points = points
        self.values = values
        self.flat = float(np.ptp(points[:, 2])) <= 1e-9
        coords = points[:, :2] if self.flat else points
        self._lattice = _lattice(coords, values)
        self._nearest: Any = None
        self._linear: Any = None
        if self._lattice is None:  # scattered samples (scipy.interpolate: only for them)
            from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator

            self._nearest = NearestNDInterpolator(coords, values)
            try:
                self._linear = LinearNDInterpolator(coords, values)
            except Exception:
                self._linear = None

    @property
    def lower_corner(self) -> NDArray[np.float64]:
        """The samples' least (x, y, z), mm: lined up with the model's lower corner."""
        corner: NDArray[np.float64] = self.points.min(axis=0)
        return corner

    @property
    def on_lattice(self) -> bool:
        """True when the samples fill a regular lattice (read by :meth:`plane`)."""
        return self._lattice is not None

    def plane(self, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The lattice's field on the plane at height ``z`` mm (data frame), linear
        between the two lattice planes about it and clamped at the lattice's bottom
        and top: (x nodes (nx,), y nodes (ny,), values (nx, ny)) float64. Only for
        samples on a lattice (:attr:`on_lattice`); a flat field's own grid."""
        assert self._lattice is not None
        axes, grid = self._lattice
        if self.flat:
            return axes[0], axes[1], grid
        zs = axes[2]
        z = min(max(float(z), float(zs[0])), float(zs[-1]))
        below = int(np.searchsorted(zs, z, side="right")) - 1
        k = min(max(below, 0), len(zs) - 2)
        t = (z - zs[k]) / (zs[k + 1] - zs[k])
        return axes[0], axes[1], (1.0 - t) * grid[:, :, k] + t * grid[:, :, k + 1]

    def at(self, x: np.ndarray, y: np.ndarray, z: float) -> np.ndarray:
        """Interpolated values at points ``x``, ``y`` (n,) float64 mm and height ``z`` mm
        in the data's own frame -> (n,) float64."""
        x = np.ravel(np.asarray(x, dtype=float))
        y = np.ravel(np.asarray(y, dtype=float))
        if self._lattice is not None:  # trilinear: bilinear on the plane at z
            xs, ys, plane = self.plane(z)
            return bilinear(xs, ys, plane, x, y)
        query = (
            np.column_stack((x, y))
            if self.flat
            else np.column_stack((x, y, np.full(x.shape, float(z))))
        )
        values = self._linear(query) if self._linear is not None else np.full(x.shape, np.nan)
        missing = ~np.isfinite(values)
        if missing.any():
            values[missing] = self._nearest(query[missing])
        return values


def bilinear(
    xs: np.ndarray, ys: np.ndarray, values: np.ndarray, x: np.ndarray, y: np.ndarray
) -> NDArray[np.float64]:
    """Bilinear interpolation of ``values`` (nx, ny) on the nodes ``xs`` (nx,), ``ys``
    (ny,) (increasing, mm) at points ``x``, ``y`` (n,) -> (n,) float64, clamped at the
    grid's edges."""
    x = np.clip(np.ravel(np.asarray(x, dtype=float)), xs[0], xs[-1])
    y = np.clip(np.ravel(np.asarray(y, dtype=float)), ys[0], ys[-1])
    i = np.clip(np.searchsorted(xs, x, side="right") - 1, 0, len(xs) - 2)
    j = np.clip(np.searchsorted(ys, y, side="right") - 1, 0, len(ys) - 2)
    tx = (x - xs[i]) / (xs[i + 1] - xs[i])
    ty = (y - ys[j]) / (ys[j + 1] - ys[j])
    low = values[i, j] + tx * (values[i + 1, j] - values[i, j])
    high = values[i, j + 1] + tx * (values[i + 1, j + 1] - values[i, j + 1])
    out: NDArray[np.float64] = low + ty * (high - low)
    return out


def _lattice(
    coords: np.ndarray, values: np.ndarray
) -> tuple[tuple[np.ndarray, ...], np.ndarray] | None:
    """The lattice's node coordinates per axis (d arrays, increasing) and its values
    (shape of the lattice) when ``coords`` (n, d) fill every node of a regular grid."""
    axes = [np.unique(coords[:, k]) for k in range(coords.shape[1])]
    shape = tuple(len(axis) for axis in axes)
    if any(n < 2 for n in shape) or int(np.prod(shape)) != coords.shape[0]:
        return None
    index = tuple(np.searchsorted(axis, coords[:, k]) for k, axis in enumerate(axes))
    grid = np.full(shape, np.nan)
    grid[index] = values
    if np.isnan(grid).any():  # repeated points leave holes: not a lattice
        return None
    return tuple(axes), grid


def load_stress(path: str | Path) -> StressData:
    """Read samples from ``path``: ``.csv`` (columns x, y, z, value; a header line is
    skipped; three columns mean x, y, value), ``.npz`` (arrays ``points`` (n, 3) and
    ``values`` (n,), or ``x``, ``y``, ``z``, ``value``) or ``.vtu`` (mesh points and a
    point-data scalar, preferably named like von_mises or stress). Raises
    ``SettingsError("infill.file", reason)``."""
    path = Path(path)
    if not str(path) or not path.is_file():
        raise SettingsError(KEY, f"no such file: {str(path)!r}")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            return _from_csv(path)
        if suffix == ".npz":
            return _from_npz(path)
        if suffix == ".vtu":
            return _from_vtu(path)
    except (OSError, ValueError, KeyError) as exc:
        if isinstance(exc, SettingsError):
            raise
        raise SettingsError(KEY, f"cannot read {path.name}: {exc}") from exc
    raise SettingsError(KEY, f"unsupported file type {suffix!r} (use .csv, .npz or .vtu)")


def _from_csv(path: Path) -> StressData:
    table = np.genfromtxt(path, delimiter=",", comments="#", dtype=float)
    table = np.atleast_2d(table)
    table = table[np.all(np.isfinite(table), axis=1)]  # drops a header row
    if table.ndim != 2 or table.shape[1] not in (3, 4):
        raise SettingsError(KEY, f"{path.name}: expected columns x,y,z,value (or x,y,value)")
    if table.shape[1] == 3:
        table = np.column_stack((table[:, :2], np.zeros(len(table)), table[:, 2]))
    return StressData(table[:, :3], table[:, 3])


def _from_npz(path: Path) -> StressData:
    with np.load(path, allow_pickle=False) as data:
        if "points" in data and "values" in data:
            points = np.asarray(data["points"], dtype=float)
            if points.ndim != 2 or points.shape[1] not in (2, 3):
                raise SettingsError(KEY, f"{path.name}: 'points' must be (n, 3)")
            if points.shape[1] == 2:
                points = np.column_stack((points, np.zeros(len(points))))
            return StressData(points, np.ravel(data["values"]))
        if all(k in data for k in ("x", "y", "value")):
            z = data["z"] if "z" in data else np.zeros_like(data["x"])
            return StressData(np.column_stack((data["x"], data["y"], z)), data["value"])
    raise SettingsError(KEY, f"{path.name}: expected arrays 'points' and 'values'")


def _from_vtu(path: Path) -> StressData:
    import meshio

    mesh = meshio.read(path)
    scalars = {
        name: np.asarray(arr, dtype=float)
        for name, arr in mesh.point_data.items()
        if np.asarray(arr).ndim == 1 or np.asarray(arr).shape[1:] == (1,)
    }
    if not scalars:
        raise SettingsError(KEY, f"{path.name}: no scalar point data")
    chosen = next((n for n in scalars if n.lower() in SCALAR_NAMES), next(iter(sorted(scalars))))
    points = np.asarray(mesh.points, dtype=float)
    if points.shape[1] == 2:
        points = np.column_stack((points, np.zeros(len(points))))
    return StressData(points, np.ravel(scalars[chosen]))
