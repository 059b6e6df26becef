"""The wave field: H = f(u) + v, f a wave of circular arcs (one a half-wave), traced exactly."""

from __future__ import annotations

import math

import numpy as np
import shapely
from numpy.typing import NDArray

from slicer.fields.base import LayerContext, register
from slicer.fields.coords import rotated, unrotated
from slicer.fields.paths import empty_paths, finish
from slicer.settings import SliceSettings

STEEPNESS = 1.0  # the curves' steepest slope (45 degrees, at the inflections) when density allows


def mean_stretch(k: float) -> float:
    """Arc length per unit run of the arc wave of steepest slope ``k``: ``theta / sin(theta)``
    with ``theta = atan(k)`` (each half-wave an arc turning ``2 theta``)."""
    theta = math.atan(k)
    return theta / math.sin(theta) if theta > 0.0 else 1.0


def steepness_for(spacing: float, line_width: float, wanted: float = STEEPNESS) -> float:
    """The largest slope ``k`` up to ``wanted`` that keeps neighbouring curves a line width
    apart at their steepest point while their mean spacing is ``spacing`` mm.

    With level step ``dc = spacing * mean_stretch(k)`` the closest approach, across the
    inflections, is ``dc * cos(theta) = spacing * theta / tan(theta)``, ``theta = atan(k)``.
    """
    ratio = line_width / spacing
    if ratio <= math.atan(wanted) / wanted:
        return wanted
    if ratio >= 1.0:
        return 0.0
    lo, hi = 0.0, math.atan(wanted)  # bisection on theta; theta / tan(theta) falls from 1
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if mid / math.tan(mid) >= ratio:
            lo = mid
        else:
            hi = mid
    return math.tan(lo)


def profile(u: np.ndarray, wavelength: float, k: float) -> NDArray[np.float64]:
    """The wave ``f(u)`` (same shape as ``u``, mm): between the inflections at whole
    half-wavelengths, circular arcs bulging up and down in turn, meeting at a slope of
    ``k`` (tangent to each other there, so the curve is smooth)."""
    half = 0.5 * wavelength
    theta = math.atan(k)
    u = np.asarray(u, dtype=np.float64)
    if theta <= 0.0:
        return np.zeros_like(u)
    radius = half / (2.0 * math.sin(theta))
    m = np.floor(u / half)
    t = u - (m + 0.5) * half
    sign = np.where(np.mod(m, 2.0) == 0.0, 1.0, -1.0)
    out: NDArray[np.float64] = sign * (
        np.sqrt(np.maximum(radius * radius - t * t, 0.0)) - radius * math.cos(theta))
    return out


@register("wave")
class WaveField:
    """Waves of wavelength ``infill.scale`` mm running along ``infill.angle`` (turned by
    90 degrees on odd layers so layers cross); each half-wave is a circular arc, so the
    G-code draws it with one ``G2``/``G3`` when arcs are on."""

    name = "wave"

    def __init__(self, settings: SliceSettings) -> None:
        self.settings = settings

    def _angle(self, ctx: LayerContext) -> float:
        return self.settings.infill_angle + (90.0 if ctx.index % 2 else 0.0)

    def _shape(self, spacing: float) -> tuple[float, float]:
        """Steepest slope k and level step (mm) for a mean spacing."""
        k = steepness_for(spacing, self.settings.line_width)
        return k, spacing * mean_stretch(k)

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64 mm."""
        spacing = self.settings.line_width / max(self.settings.infill_density, 1e-3)
        k, _ = self._shape(spacing)
        u, v = rotated(x, y, ctx.bounds, self._angle(ctx))
        values: NDArray[np.float64] = profile(u, self.settings.infill_scale, k) + v
        return values

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Curves ``v = c_j - f(u)``, ``c_j`` a level step apart, clipped to ``region``;
        sampled on a grid of ``u`` with a point on every inflection."""
        if region.is_empty or not math.isfinite(spacing) or spacing <= 0:
            return empty_paths()
        k, step = self._shape(spacing)
        scale = self.settings.infill_scale
        amplitude = profile(np.array([0.25 * scale]), scale, k)[0]
        angle = self._angle(ctx)
        xmin, ymin, xmax, ymax = region.bounds
        u, v = rotated(
            np.array([xmin, xmax, xmax, xmin]),
            np.array([ymin, ymin, ymax, ymax]),
            ctx.bounds,
            angle,
        )
        levels = np.arange(np.floor((v.min() - amplitude) / step),
                           np.ceil((v.max() + amplitude) / step) + 1)
        half = 0.5 * scale
        du = half / math.ceil(half / min(scale / 48.0, self.settings.line_width))
        us = np.arange(math.floor(u.min() / du) - 1, math.ceil(u.max() / du) + 2) * du
        vv = levels[:, None] * step - profile(us, scale, k)[None, :]
        uu = np.broadcast_to(us, vv.shape)
        xs, ys = unrotated(uu.ravel(), vv.ravel(), ctx.bounds, angle)
        owner = np.repeat(np.arange(levels.size), us.size)
        lines = shapely.linestrings(np.column_stack((xs, ys)), indices=owner)
        return finish(lines, region, self.settings.line_width)
