"""Remaining print time: the slicer's estimates, refitted on how fast the printer really goes."""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np
import shapely

from slicer.gcode import GcodeSummary, filament_grams

log = logging.getLogger("hostd.eta")

RECENT_LAYERS = 8  # sliced layers that scale the geometry's guess for the unsliced ones
WINDOW_SHARE = 0.5  # the refit weighs the latest half of the printed estimate more


class EtaModel:
    """Remaining seconds of a sliced job from acknowledged progress.

    - Each sliced layer has the slicer's estimate (``schedule.estimates``);
      a layer not sliced yet is guessed from its geometry (infill area over
      line width and speed, walls over wall speed, both rough) times the ratio
      of the slicer's estimate to that guess over the latest sliced layers. A
      cancelled body's area leaves the guess from its first layer on; a retune
      shows in the next sliced layer's estimate, so both move the ETA within
      one layer.
    - The printer's pace: actual seconds per estimated second over the
      layers printed, the latest half (by estimated time) counted twice.
    - ETA = pace x estimated seconds left - the time already spent in the
      layer being printed (at most its own share).

    Without estimates (a G-code job) it falls back to the mean layer time.
    """

    def __init__(self, schedule: Any, layers: int, first: int) -> None:
        self.schedule = schedule
        self.layers = layers
        self.first = first
        self.started: float | None = None
        self.done_at: dict[int, float] = {}
        self.last_done = first - 1
        self._geometry: tuple[np.ndarray, np.ndarray] | None = None  # (n, bodies) guesses
        self._thread: threading.Thread | None = None

    def start(self, now: float) -> None:
        """The start block is acknowledged: printing begins now."""
        self.started = now

    def layer_done(self, layer: int, now: float) -> None:
        """Every line of ``layer`` is acknowledged at ``now`` (monotonic seconds).

        The first layer done that extruded starts measuring the geometry of every
        layer: not sooner, so that cutting the whole model never delays the first
        extrusion.
        """
        self.done_at[layer] = now
        self.last_done = layer
        if self.schedule is not None and self._thread is None and self._printed(layer):
            self._thread = threading.Thread(target=self._measure, name="hostd-eta", daemon=True)
            self._thread.start()

    def _printed(self, layer: int) -> bool:
        """Whether ``layer`` laid filament, by the slicer's estimate (unknown: yes)."""
        estimate = self.schedule.estimates.get(layer)
        return estimate is None or estimate[1] > 0

    def _measure(self) -> None:
        """Each layer's rough time per body, (layers, bodies) s, from its outline polygons."""
        try:
            plan = self.schedule.base_plan
            settings = self.schedule.base_settings
            bodies = max(1, plan.body_count)
            area = np.zeros((self.layers, bodies))
            walls = np.zeros((self.layers, bodies))
            for i in range(self.layers):
                polys, owner = plan.layer_bodies(i)
                if len(polys):
                    np.add.at(area[i], owner, shapely.area(polys))
                    np.add.at(walls[i], owner, shapely.length(polys))
            solid = solid_area(area, settings.top_layers, settings.bottom_layers)
            line = settings.line_width * settings.print_speed
            seconds = ((area - solid) * max(settings.infill_density, 0.05) / line + solid / line
                       + walls * max(1, settings.perimeters) / settings.wall_speed)
            self._geometry = (seconds, np.arange(bodies))
        except Exception:  # the ETA falls back to the slicer's recent layers
            log.debug("layer geometry for the ETA not measured", exc_info=True)

    def _estimates(self) -> np.ndarray | None:
        """Estimated seconds of every layer: the slicer's, or the scaled guess, (layers,)."""
        if self.schedule is None:
            return None
        known = dict(self.schedule.estimates)
        if not known:
            return None
        out = np.full(self.layers, np.nan)
        for layer, (seconds, _filament) in known.items():
            if 0 <= layer < self.layers:
                out[layer] = seconds
        missing = np.isnan(out)
        if not missing.any():
            return out
        geometry = self._geometry
        if geometry is None:
            recent = out[~missing][-RECENT_LAYERS:]
            out[missing] = recent.mean()
            return out
        guess, bodies = geometry
        excluded = np.zeros_like(guess, dtype=bool)
        for body, first in self.schedule.cancelled:
            if 0 <= body < len(bodies):
                excluded[first:, body] = True
        per_layer = np.where(excluded, 0.0, guess).sum(axis=1)
        sliced = np.flatnonzero(~missing)[-RECENT_LAYERS:]
        scale = out[sliced].sum() / max(per_layer[sliced].sum(), 1e-9)
        out[missing] = per_layer[missing] * scale
        return out

    def pace(self, estimates: np.ndarray) -> float | None:
        """Actual seconds per estimated second over the layers printed (None before one)."""
        if self.started is None or self.last_done < self.first:
            return None
        layers = np.arange(self.first, self.last_done + 1)
        ends = np.array([self.done_at.get(i, np.nan) for i in layers])
        starts = np.concatenate([[self.started], ends[:-1]])
        actual = ends - starts
        planned = estimates[layers]
        ok = ~np.isnan(actual) & ~np.isnan(planned)
        actual, planned = actual[ok], planned[ok]
        if not len(planned) or planned.sum() <= 0:
            return None
        # the latest half of the estimated time counts twice: a retune or a cancelled body
        # shows in the pace soon, one slow layer does not swing it
        cumulative = np.cumsum(planned[::-1])[::-1]
        weight = np.where(cumulative <= WINDOW_SHARE * planned.sum(), 2.0, 1.0)
        return float((weight * actual).sum() / max((weight * planned).sum(), 1e-9))

    def remaining(self, now: float) -> float | None:
        """Seconds left, or None until a layer has been printed."""
        if self.started is None or self.last_done < self.first:
            return None
        estimates = self._estimates()
        current = self.last_done + 1
        since = now - self.done_at.get(self.last_done, now)
        if estimates is None or np.isnan(estimates).all():
            done = self.last_done - self.first + 1
            per_layer = (self.done_at[self.last_done] - self.started) / max(done, 1)
            return max(0.0, per_layer * (self.layers - current) - since)
        pace = self.pace(estimates)
        if pace is None:
            return None
        left = np.nansum(estimates[current:]) * pace
        in_layer = estimates[current] * pace if current < self.layers else 0.0
        return float(max(0.0, left - min(since, in_layer)))


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


def slicer_totals(schedule: Any) -> tuple[GcodeSummary, list[float]] | None:
    """The job's totals and layer times as ``hostd slice`` counts them (the sum of the
    slicer's per-layer figures), when every layer was sliced in this run; else None."""
    if schedule is None:
        return None
    known = dict(schedule.estimates)
    count = schedule.layer_count
    if sorted(known) != list(range(count)):
        return None
    times = [known[i][0] for i in range(count)]
    filament = sum(known[i][1] for i in range(count))
    settings = schedule.base_settings
    return GcodeSummary(count, filament, filament_grams(filament, settings), sum(times)), times
