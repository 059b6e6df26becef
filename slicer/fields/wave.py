"""The wave field: H = a sin(b u) + v, whose level sets are sine curves, traced exactly."""

from __future__ import annotations

import math

import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.special import ellipe

from slicer.fields.base import LayerContext, register
from slicer.fields.coords import rotated, unrotated
from slicer.fields.paths import empty_paths, finish
from slicer.settings import SliceSettings

STEEPNESS = 1.0  # a * b: the curves' steepest slope (45 degrees) when the density allows it


def mean_stretch(k: float) -> float:
    """Mean of sqrt(1 + k^2 cos^2 t) over a period: arc length per unit run of a sine of slope k."""
    m = k * k / (1.0 + k * k)
    return (2.0 / math.pi) * math.sqrt(1.0 + k * k) * float(ellipe(m))


def steepness_for(spacing: float, line_width: float, wanted: float = STEEPNESS) -> float:
    """The largest slope ``a * b`` up to ``wanted`` that keeps neighbouring curves a line width
    apart at their steepest point while their mean spacing is ``spacing`` mm.

    With level step ``dc = spacing * mean_stretch(k)`` the closest approach is
    ``dc / sqrt(1 + k^2) = spacing * (2 / pi) * E(k^2 / (1 + k^2))``.
    """
    ratio = line_width / spacing
    if ratio <= 2.0 / math.pi:
        return wanted
    if ratio >= 1.0:
        return 0.0
    lo, hi = 0.0, 1.0  # bisection on m; E(m) falls from pi/2 to 1
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if (2.0 / math.pi) * float(ellipe(mid)) >= ratio:
            lo = mid
        else:
            hi = mid
    return min(wanted, math.sqrt(lo / (1.0 - lo)))


@register("wave")
class WaveField:
    """Sine curves of wavelength ``infill.scale`` mm running along ``infill.angle``
    (turned by 90 degrees on odd layers so layers cross)."""

    name = "wave"

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings

    def _angle(self, ctx: LayerContext) -> float:
        return self.settings.infill_angle + (90.0 if ctx.index % 2 else 0.0)

    def _shape(self, spacing: float) -> tuple[float, float, float]:
        """Amplitude a (mm), wavenumber b (1/mm) and level step (mm) for a mean spacing."""
        b = 2.0 * math.pi / self.settings.infill_scale
        k = steepness_for(spacing, self.settings.line_width)
        return k / b, b, spacing * mean_stretch(k)

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm."""
        spacing = self.settings.line_width / max(self.settings.infill_density, 1e-3)
        a, b, _ = self._shape(spacing)
        u, v = rotated(x, y, ctx.bounds, self._angle(ctx))
        values: NDArray[np.float64] = a * np.sin(b * u) + v
        return values

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Curves ``v = c_k - a sin(b u)``, ``c_k`` a level step apart, clipped to ``region``."""
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        a, b, step = self._shape(spacing)
        angle = self._angle(ctx)
        xmin, ymin, xmax, ymax = region.bounds
        u, v = rotated(
            np.array([xmin, xmax, xmax, xmin]),
            np.array([ymin, ymin, ymax, ymax]),
            ctx.bounds,
            angle,
        )
        levels = np.arange(np.floor((v.min() - a) / step), np.ceil((v.max() + a) / step) + 1)
        du = min(self.settings.infill_scale / 48.0, self.settings.line_width)
        us = np.arange(u.min() - du, u.max() + 2.0 * du, du)
        vv = levels[:, None] * step - a * np.sin(b * us)[None, :]
        uu = np.broadcast_to(us, vv.shape)
        xs, ys = unrotated(uu.ravel(), vv.ravel(), ctx.bounds, angle)
        owner = np.repeat(np.arange(levels.size), us.size)
        lines = shapely.linestrings(np.column_stack((xs, ys)), indices=owner)
        return finish(lines, region, self.settings.line_width)
