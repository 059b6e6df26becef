"""The stress field (Eq. 14): a scalar field read from a file modulating the linear field."""

from __future__ import annotations

import logging
import math
import threading
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slicer.fields.base import LayerContext, register
from slicer.fields.coords import centre
from slicer.fields.grid import Grid, GridField
from slicer.fields.stress_pending import pending, waiting
from slicer.settings import SettingsError, SliceSettings

if TYPE_CHECKING:
    from slicer.fields.stress_data import StressData

KEY = "infill.file"

log = logging.getLogger("slicer.stress")

SLAB_CELL = 2.0  # line widths between the nodes the samples are first interpolated to
SLAB_NODES = 40_000  # at most this many such nodes per layer
FLOOR = 0.05  # least modulation, as a fraction of the scale, so unloaded areas keep sparse lines
SCALE_PERCENTILE = 99.0  # the stress the field is scaled to: this percentile over the part
PLANES_KEPT = 8  # lattice planes kept (layers being sliced at once, and a few more)
AXIS_SAMPLES = 1024  # stations along the long axis where variant B reads the field


@register("stress")
class StressField(GridField):
    """H = sigma(x, y, z) * H_lin(x, y, z; t) * k, the paper's Eq. 14.

    ``sigma`` is read from ``infill.file`` (see :func:`load_stress`), scaled to the
    99th percentile of the stress over the part (:func:`stress_scale`: a peak at a
    re-entrant corner grows without bound as the mesh is refined, the percentile
    converges) and kept between 5 % and 1, ``H_lin = x sin t + y cos t (-1)^layer`` with
    ``t = infill.angle``; ``k`` is set by the level placement from
    ``infill.density``. The file's samples are in the model's own frame: their
    lower corner is lined up with the placed model's. Contours crowd where the
    stress is high (down to one line width) and thin out where it is low (up to
    six times the mean spacing). With ``infill.stress = "optimal"`` the file holds
    an optimised density and the field is ``H_lin`` itself, its straight lines
    thinned by whole octaves where the density is low (:meth:`line_density`), so
    the line density follows the density itself.
    """

    name = "stress"
    gap = 6.0
    cell_fraction = 0.5

    def __init__(self, settings: SliceSettings) -> None:
        super().__init__(settings)
        if not settings.infill_file:
            raise SettingsError(KEY, "the stress field needs a file of x,y,z,value samples")
        self._pending = pending(settings.infill_file)
        self._loaded = threading.Lock()
        self._data: StressData | None = None
        self.peak = 1.0
        self.profile: tuple[int, np.ndarray, np.ndarray] | None = None
        self._planes: dict[object, Any] = {}  # lattice planes and lines, by layer
        if self._pending is None:
            self._load()

    def _load(self) -> None:
        from slicer.fields.stress_data import load_stress  # when first sampled

        data = load_stress(self.settings.infill_file)
        if self.settings.infill_stress == "optimal":  # a density: scaled to its peak
            self.peak = float(np.max(np.abs(data.values))) or 1.0
        else:
            self.peak = stress_scale(self.settings.infill_file, data.values)
        self.profile = axis_profile(data) if self.settings.infill_stress == "B" else None
        self._data = data

    @property
    def data(self) -> StressData:
        """The field's samples; waits for an analysis still running (see :func:`pending`)."""
        if self._data is None and self._pending is not None and not self._pending.done():
            log.info("a layer waits for the stress analysis of %s", self.settings.infill_file)
            with waiting(self.settings.infill_file), self._loaded:
                if self._data is None:
                    assert self._pending is not None
                    self._pending.result()  # raises the analysis' own error
                    self._load()
        assert self._data is not None
        return self._data

    def stress(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Interpolated field from the file at points (n,) mm on this layer -> (n,) float64.

        Samples on a lattice (the built-in analysis' field) are read bilinearly
        from the lattice's plane at mid-layer height (interpolated between the two
        lattice planes about it, once per layer and cached). Scattered samples are
        interpolated once per call onto a slab of nodes every ``SLAB_CELL`` line
        widths over the model's footprint at mid-layer height, and the points read
        from that slab bilinearly: the scattered 3D interpolation then costs
        thousands of look-ups, not one per grid node.
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        corner = self.data.lower_corner  # (waits for a pending analysis first)
        if self.profile is not None:
            xmin, ymin = ctx.bounds[:2]
            mid = max(ctx.z - 0.5 * self.settings.layer_height, 0.0) + corner[2]
            frame = (x - xmin + corner[0], y - ymin + corner[1], np.full(x.shape, mid))
            axis, stations, values = self.profile
            along: NDArray[np.float64] = np.interp(frame[axis], stations, values)
            return along
        mid_z = max(ctx.z - 0.5 * self.settings.layer_height, 0.0)
        xmin, ymin, xmax, ymax = ctx.bounds
        if self.data.on_lattice:  # the analysis' own lattice: its plane at this height
            from slicer.fields.stress_data import bilinear

            xs, ys, plane = self._plane(mid_z + corner[2])
            return bilinear(xs, ys, plane, x.ravel() - xmin + corner[0],
                            y.ravel() - ymin + corner[1]).reshape(x.shape)
        cell = SLAB_CELL * self.settings.line_width
        cell = max(cell, math.sqrt((xmax - xmin + cell) * (ymax - ymin + cell) / SLAB_NODES))
        xs = np.arange(xmin - cell, xmax + 2.0 * cell, cell)
        ys = np.arange(ymin - cell, ymax + 2.0 * cell, cell)
        gx, gy = np.meshgrid(xs, ys)
        slab = self.data.at(
            gx.ravel() - xmin + corner[0], gy.ravel() - ymin + corner[1], mid_z + corner[2]
        ).reshape(gx.shape)
        from scipy.interpolate import RegularGridInterpolator

        read = RegularGridInterpolator((ys, xs), slab)
        points = np.column_stack(
            (np.clip(y.ravel(), ys[0], ys[-1]), np.clip(x.ravel(), xs[0], xs[-1]))
        )
        sampled: NDArray[np.float64] = read(points).reshape(x.shape)
        return sampled

    def _plane(self, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The lattice's plane at height ``z`` (data frame), cached: a layer's field is
        sampled several times (its grid, the pictures) from the same plane."""
        with self._loaded:
            known = self._planes.get(z)
        if known is None:
            known = self.data.plane(z)
            with self._loaded:
                self._planes[z] = known
                while len(self._planes) > PLANES_KEPT:
                    self._planes.pop(next(iter(self._planes)))
        return known

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        cx, cy = centre(ctx.bounds)
        t = math.radians(self.settings.infill_angle)
        mirror = -1.0 if ctx.index % 2 else 1.0
        linear = (x - cx) * math.sin(t) + (y - cy) * math.cos(t) * mirror
        if self.settings.infill_stress == "optimal":  # straight lines: line_density spaces them
            return linear
        stress = self.stress(x, y, ctx)  # loads the field first: peak is known after it
        sigma = np.clip(np.abs(stress) / self.peak, FLOOR, 1.0)
        field: NDArray[np.float64] = (sigma.reshape(x.shape) * linear).reshape(x.shape)
        return field


    def line_density(self, grid: Grid, ctx: LayerContext) -> np.ndarray | None:
        """With ``infill.stress = "optimal"``: the optimised density on the grid's nodes
        (ny, nx), scaled to its peak and floored at 5 %, which the straight lines'
        spacing follows (:func:`slicer.fields.density_levels.density_plan`); else None."""
        if self.settings.infill_stress != "optimal":
            return None
        xx, yy = grid.mesh()
        rho = self.stress(xx.ravel(), yy.ravel(), ctx)
        density: NDArray[np.float64] = np.maximum(np.abs(rho) / self.peak, FLOOR)
        return density.reshape(xx.shape)


def stress_scale(path: str, values: np.ndarray) -> float:
    """The stress a field is scaled to: the ``scale`` the analysis wrote in its field
    file (the :data:`SCALE_PERCENTILE` th percentile of its elements' von Mises stress,
    all of one volume), else that percentile of the file's values (an imported file)."""
    if str(path).lower().endswith(".npz"):
        with np.load(path, allow_pickle=False) as data:
            if "scale" in data:
                return float(data["scale"]) or 1.0
    return float(np.percentile(np.abs(values), SCALE_PERCENTILE)) or 1.0


def axis_profile(data: StressData) -> tuple[int, np.ndarray, np.ndarray]:
    """Variant B's field: ``sigma`` along the long axis of the samples' box through its
    centre (the paper's ``sigma_vm(x, 0, 0)`` for a specimen along x).

    The long axis is the samples' box's longest side (x, y or z; the first of
    equal ones); the line runs through the middle of the other two sides. Returns
    (axis 0..2, stations (m,) mm along it, values (m,)) in the data's own frame;
    the field at any point is the profile's value at the point's station.
    """
    lo = data.points.min(axis=0)
    hi = data.points.max(axis=0)
    axis = int(np.argmax(hi - lo))
    stations = np.linspace(lo[axis], hi[axis], AXIS_SAMPLES)
    line = np.tile((lo + hi) / 2.0, (AXIS_SAMPLES, 1))
    line[:, axis] = stations
    if data.flat or axis != 2:  # one height: one look-up of the whole line
        values = data.at(line[:, 0], line[:, 1], float(line[0, 2]))
    else:  # a vertical line: one look-up per height (once per job)
        values = np.concatenate([data.at(p[0:1], p[1:2], float(p[2])) for p in line])
    return axis, stations, values
