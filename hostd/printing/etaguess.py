"""Print time of layers not sliced yet: a geometric guess, calibrated on a few sampled layers.

The guess of a layer, per body, in seconds: its walls (the outline offset inwards
to the middle of each wall, lengths over the wall speed), its solid fill (skins,
where the infill domain is not covered by all of the top or bottom layers' domains,
compared by area, and the thin parts where the walls leave a gap) and its sparse
infill (domain area times density), over the line width and the fill speed, plus
a fixed cost per layer and per island (lift, retractions). What the guess misses
(corners, short lines, acceleration) varies slowly along the model, so the ratio
of the slicer's estimate to the guess is measured on a few layers spread over
the print time and interpolated between them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from slicer.paths.layer import fill_distance
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

# fixed costs guessed per layer (lift, a retraction, the travel in) and per island, s
LAYER_COST_S = 0.3
ISLAND_COST_S = 0.15
# layers sliced for their estimate alone: this many spread over the guessed print time,
# as many over the layers
SAMPLES = 12


@dataclass(frozen=True)
class Geometry:
    """What each layer and body holds, (layers, bodies) float64: wall length (mm, every
    wall), solid and sparse fill area (mm^2), islands."""

    walls: np.ndarray
    solid: np.ndarray
    sparse: np.ndarray
    islands: np.ndarray

    def seconds(self, settings: SliceSettings, layers: slice = slice(None)) -> np.ndarray:
        """Guessed seconds of ``layers`` with ``settings``, (k, bodies)."""
        rows = np.arange(len(self.walls))[layers]
        first = rows == 0
        wall_v = np.where(first, settings.first_layer_speed, settings.wall_speed)[:, None]
        fill_v = np.where(first, settings.first_layer_speed, settings.print_speed)[:, None]
        w = settings.line_width
        sparse = self.sparse[layers] * max(settings.infill_density, 0.0)
        islands = self.islands[layers]
        seconds = self.walls[layers] / wall_v + (self.solid[layers] + sparse) / (w * fill_v)
        total = np.maximum(islands.sum(axis=1, keepdims=True), 1.0)
        return seconds + islands * ISLAND_COST_S + LAYER_COST_S * islands / total

    def filament(self, settings: SliceSettings, layers: slice = slice(None)) -> np.ndarray:
        """Guessed filament (mm) of ``layers`` with ``settings``, (k, bodies): the roads'
        volume (walls, solid fill, sparse fill at its density; one line wide, one layer
        high) over the filament's cross-section."""
        rows = np.arange(len(self.walls))[layers]
        height = np.where(rows == 0, settings.first_layer_height, settings.layer_height)[:, None]
        w = settings.line_width
        sparse = self.sparse[layers] * max(settings.infill_density, 0.0)
        volume = (self.walls[layers] * w + self.solid[layers] + sparse) * height
        return volume / settings.filament_area


def measure(plan: SlicePlan, settings: SliceSettings) -> Geometry:
    """The :class:`Geometry` of every layer of ``plan`` (outlines offset, vectorised)."""
    n, bodies = plan.layer_count, max(1, plan.body_count)
    parts, layer_of, body_of = [], [], []
    for i in range(n):
        polys, owner = plan.layer_bodies(i)
        parts.append(polys)
        layer_of.append(np.full(len(polys), i))
        body_of.append(np.asarray(owner, dtype=np.int64))
    empty = np.zeros((n, bodies))
    if not sum(len(p) for p in parts):
        return Geometry(empty, empty, empty, empty)
    polys = np.concatenate(parts)
    cell = np.concatenate(layer_of) * bodies + np.concatenate(body_of)
    w = settings.line_width

    def per_cell(values: np.ndarray) -> np.ndarray:
        return np.bincount(cell, weights=values, minlength=n * bodies).reshape(n, bodies)

    area = shapely.area(polys)
    walls = np.zeros(len(polys))
    for k in range(max(0, settings.perimeters)):
        walls += shapely.length(shapely.buffer(polys, -(k + 0.5) * w, quad_segs=2))
    domain = shapely.area(shapely.buffer(polys, -fill_distance(settings), quad_segs=2))
    gap = np.clip(area - domain - walls * w, 0.0, None)
    fill = per_cell(domain)
    skin = solid_area(fill, settings.top_layers, settings.bottom_layers)
    return Geometry(per_cell(walls), skin + per_cell(gap), np.clip(fill - skin, 0.0, None),
                    per_cell(np.ones(len(polys))))


def solid_area(area: np.ndarray, top: int, bottom: int) -> np.ndarray:
    """Area (mm^2) of each layer and body to be filled solid, (layers, bodies): what the
    ``top`` layers above or the ``bottom`` below do not all cover (areas only, a guess)."""
    layers = area.shape[0]
    padded = np.concatenate([np.zeros((bottom, area.shape[1])), area,
                             np.zeros((top, area.shape[1]))])
    covered = area.copy()
    for k in range(1, top + 1):
        covered = np.minimum(covered, padded[bottom + k: bottom + k + layers])
    for k in range(1, bottom + 1):
        covered = np.minimum(covered, padded[bottom - k: bottom - k + layers])
    return area - covered


def sample_layers(guess: np.ndarray, count: int | None = None) -> np.ndarray:
    """Layers to slice for calibration, ascending, in pairs (a layer and the next, as
    hatch directions alternate): ``count`` pairs (by default the larger of
    :data:`SAMPLES` and a twentieth of the layers) spread evenly over the guessed time
    ``guess`` (layers,) s, as many over the layers, as many over the guess's relative
    changes from layer to layer (where the shape changes fast), and the layers on either
    side of a jump of the guess by half or more."""
    n = len(guess)
    count = max(SAMPLES, n // 20) if count is None else count
    cumulative = np.cumsum(guess)
    if n == 0 or cumulative[-1] <= 0:
        return np.zeros(0, dtype=np.int64)
    marks = (np.arange(count) + 0.5) / count
    by_time = np.searchsorted(cumulative, marks * cumulative[-1])
    by_layer = (marks * n).astype(np.int64)
    previous = np.concatenate(([0.0], guess[:-1]))
    change = np.abs(guess - previous) / np.maximum(np.maximum(previous, guess), 1e-9)
    jumps = np.flatnonzero(change > 0.5)
    turning = np.cumsum(change)
    by_change = np.searchsorted(turning, marks * turning[-1])
    firsts = np.concatenate([by_time, by_layer, by_change, jumps - 2, jumps])
    chosen = np.unique(np.concatenate([firsts, firsts + 1]))
    chosen = chosen[(chosen >= 0) & (chosen < n)]
    return chosen[guess[chosen] > 0].astype(np.int64)


def calibrated(guess: np.ndarray, anchors: dict[int, tuple[float, float]]) -> np.ndarray:
    """Each layer's guess (layers,) s times the ratio of estimate to guess interpolated
    (linearly in the layer number, held beyond the ends) between ``anchors``: layer ->
    (its estimate, its guess) s. Anchors on consecutive layers are taken in sliding pairs,
    between them, with the ratio of their sums (so alternating layers do not bias it).
    Without anchors the guess as it is."""
    if not anchors:
        return guess.copy()
    layers = np.array(sorted(anchors))
    estimate = np.array([anchors[i][0] for i in layers.tolist()])
    guessed = np.array([anchors[i][1] for i in layers.tolist()])
    paired = layers[1:] == layers[:-1] + 1
    has_pair = np.zeros(len(layers), dtype=bool)
    has_pair[1:] |= paired
    has_pair[:-1] |= paired
    at = np.concatenate([layers[:-1][paired] + 0.5, layers[~has_pair]])
    top = np.concatenate([(estimate[:-1] + estimate[1:])[paired], estimate[~has_pair]])
    bottom = np.concatenate([(guessed[:-1] + guessed[1:])[paired], guessed[~has_pair]])
    ok = bottom > 0
    if not ok.any():
        return guess.copy()
    order = np.argsort(at[ok])
    ratio = (top[ok] / bottom[ok])[order]
    return guess * np.interp(np.arange(len(guess)), at[ok][order], ratio)
