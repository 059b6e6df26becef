"""The eggcrate field: H = sin(a u)^2 + sin(a v)^2, a cell pattern of period infill.scale."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import shapely
from numpy.typing import NDArray

from slicer.fields.base import LayerContext, register
from slicer.fields.coords import centre, rotated
from slicer.fields.grid import GridField
from slicer.settings import SliceSettings

MIN_PERIOD = 4.0  # least period, in infill spacings


@register("eggcrate")
class EggcrateField(GridField):
    """Bumps and dimples of period ``infill.scale`` mm along axes turned by ``infill.angle``.

    Levels near 0 and 2 are rings around the dimples and bumps, level 1 the
    diagonal lattice through the saddles, always drawn so the infill is one
    connected web (cut briefly where its lines cross, to keep them a line width
    apart); the level placement keeps the rings apart.
    """

    name = "eggcrate"
    anchor = 1.0  # the saddle level: a connected diagonal lattice through every cell
    shared_levels = True  # H ignores the layer's shape: one level step for every layer
    periods = 3  # the reference square's side, in periods

    def __init__(self, settings: SliceSettings) -> None:
        super().__init__(settings)
        self._periods: dict[float, EggcrateField] = {}

    def reference(self, ctx: LayerContext) -> shapely.Geometry:
        """A square of a few whole periods at the model's centre (the pattern repeats)."""
        cx, cy = centre(ctx.bounds)
        half = 0.5 * self.periods * self.settings.infill_scale
        return shapely.box(cx - half, cy - half, cx + half, cy + half)

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Level sets clipped to ``region`` at mean ``spacing`` mm. The period grows to
        ``MIN_PERIOD`` spacings when ``infill.scale`` is smaller, since the lattice
        alone would otherwise be denser than a sparse density asks for."""
        wanted = MIN_PERIOD * spacing
        if math.isfinite(wanted) and wanted > self.settings.infill_scale:
            return self._with_period(wanted).paths(region, ctx, spacing)
        return super().paths(region, ctx, spacing)

    def _with_period(self, period: float) -> EggcrateField:
        period = min(period, 200.0)
        with self._lock:
            field = self._periods.get(period)
            if field is None:
                field = EggcrateField(replace(self.settings, infill_scale=period))
                self._periods[period] = field
        return field

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 in [0, 2]."""
        u, v = rotated(x, y, ctx.bounds, self.settings.infill_angle)
        density = self.settings.infill_density
        spacing = self.settings.line_width / density if density > 0 else 0.0
        a = math.pi / min(max(self.settings.infill_scale, MIN_PERIOD * spacing), 200.0)
        values: NDArray[np.float64] = np.sin(a * u) ** 2 + np.sin(a * v) ** 2
        return values
