"""Remaining print time: the slicer's estimates, refitted on how fast the printer really goes."""

from __future__ import annotations

import itertools
import logging
import threading
from typing import Any

import numpy as np

from hostd.printing.etaguess import Geometry, calibrated, measure, sample_layers
from slicer.output.gcode import END_LIFT, GcodeSummary, filament_grams
from slicer.output.layertime import lift_time

log = logging.getLogger("hostd.printing.eta")

RECENT_LAYERS = 8  # sliced layers whose mean stands for the others before the geometry
PLANNER_BLOCKS = 16  # Marlin's BLOCK_BUFFER_SIZE: moves acknowledged but not yet made
WINDOW_SHARE = 0.5  # the refit weighs the latest half of the printed estimate more


class EtaModel:
    """Remaining seconds of a sliced job from acknowledged progress.

    - Each sliced layer has the slicer's estimate (``schedule.estimates``, the
      planner's time for its moves: :mod:`slicer.output.layertime`). A layer not sliced
      yet is guessed from the model's geometry with its own settings, less its
      cancelled bodies (:mod:`hostd.printing.etaguess`), times the ratio of estimate to
      guess interpolated between the layers sliced so far and a few layers
      sliced in the background for their estimate alone. A retune or a cancel
      moves the guess of every layer it touches at once.
    - The printer's pace: actual seconds per estimated second over the layers
      printed, the latest half (by estimated time) counted twice; time spent
      paused is left out.
    - ETA = pace x (estimated seconds left + the end block's lift + the moves of
      the last layer done still in the printer's planner) - the time already
      spent in the layer being printed (at most its own share).

    Without estimates (a G-code job) it falls back to the mean layer time.
    """

    def __init__(self, schedule: Any, layers: int, first: int) -> None:
        self.schedule = schedule
        self.layers = layers
        self.first = first
        self.started: float | None = None
        self.done_at: dict[int, float] = {}  # layer -> active seconds when it was done
        self.last_done = first - 1
        self._geometry: Geometry | None = None
        # layer -> ((estimate s, filament mm), retunes made then, bodies left out then)
        self._samples: dict[int, tuple[tuple[float, float], int, frozenset[int]]] = {}
        self._filament: tuple[Any, tuple[float, float] | None] | None = None  # (key, figures)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._paused_total = 0.0
        self._paused_since: float | None = None

    def start(self, now: float, measure_now: bool = True) -> None:
        """The start block is acknowledged: printing begins now. Measures the geometry
        and samples a few layers in a background thread: at once, or (``measure_now``
        False, as the daemon does) once the first layer that laid filament is done, so
        that this work never delays the first extrusion."""
        self.started = self._active(now)
        if measure_now:
            self._begin_measuring()

    def _begin_measuring(self) -> None:
        if self.schedule is not None and self._thread is None:
            self._thread = threading.Thread(target=self._measure, name="hostd-eta", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """The job is over: the background sampling stops after its current layer."""
        self._stop.set()

    @property
    def measuring(self) -> bool:
        """Whether the background measuring thread is still running."""
        thread = self._thread
        return thread is not None and thread.is_alive()

    def wait_measured(self, timeout: float | None = None) -> bool:
        """Wait until the geometry and the samples are ready (or failed); False on timeout."""
        thread = self._thread
        if thread is not None:
            thread.join(timeout)
            return not thread.is_alive()
        return True

    def pause(self, now: float) -> None:
        """Printing paused at ``now``: time from here to :meth:`resume` is not printing."""
        if self._paused_since is None:
            self._paused_since = now

    def resume(self, now: float) -> None:
        """Printing goes on at ``now``."""
        if self._paused_since is not None:
            self._paused_total += max(0.0, now - self._paused_since)
            self._paused_since = None

    def _active(self, now: float) -> float:
        """``now`` less the time spent paused."""
        paused = self._paused_total
        if self._paused_since is not None:
            paused += max(0.0, now - self._paused_since)
        return now - paused

    def layer_done(self, layer: int, now: float) -> None:
        """Every line of ``layer`` is acknowledged at ``now`` (monotonic seconds)."""
        self.done_at[layer] = self._active(now)
        self.last_done = layer
        if self._thread is None and self._printed(layer):
            self._begin_measuring()

    def _printed(self, layer: int) -> bool:
        """Whether ``layer`` laid filament, by the slicer's estimate (unknown: yes)."""
        estimate = self.schedule.estimates.get(layer) if self.schedule is not None else None
        return estimate is None or estimate[1] > 0

    def _measure(self) -> None:
        """The geometry of every layer, then the estimate of a few sampled layers."""
        try:
            schedule = self.schedule
            geometry = schedule.on_plan(measure, schedule.base_settings)
            self._geometry = geometry
            guess = geometry.seconds(schedule.base_settings).sum(axis=1)
            for layer in sample_layers(guess).tolist():
                if self._stop.is_set():
                    return
                if layer in schedule.estimates or layer <= self.last_done:
                    continue
                retunes = len(schedule.changes)
                excluded = schedule.excluded_at(layer)
                code = schedule.fresh_code(layer)
                self._samples[layer] = ((code.time_s, code.filament_mm), retunes, excluded)
        except Exception:  # the ETA falls back to the slicer's recent layers
            log.debug("layer geometry for the ETA not measured", exc_info=True)

    def _guess(self, lo: int, hi: int, column: int = 0) -> np.ndarray:
        """Guessed seconds (``column`` 0) or filament mm (1) of layers ``lo..hi-1`` with
        their settings, less the cancelled bodies, (hi - lo,); needs the geometry."""
        geometry = self._geometry
        assert geometry is not None
        schedule = self.schedule
        guess = geometry.filament if column else geometry.seconds
        bounds = sorted({lo, hi, *(f for f, _ in schedule.changes if lo < f < hi)})
        rows = [guess(schedule.settings_at(a), slice(a, b))
                for a, b in itertools.pairwise(bounds)]
        seconds = np.concatenate(rows) if rows else np.zeros((0, geometry.walls.shape[1]))
        bodies = seconds.shape[1]
        for body, first in list(schedule.cancelled):
            if 0 <= body < bodies and first < hi:
                seconds[max(first, lo) - lo:, body] = 0.0
        return seconds.sum(axis=1)

    def _valid_samples(self, column: int = 0) -> dict[int, float]:
        """The sampled estimates (``column`` 0: s, 1: filament mm) no later retune or
        cancel made stale."""
        schedule = self.schedule
        out = {}
        for layer, (figures, retunes, excluded) in list(self._samples.items()):
            if all(first > layer for first, _ in schedule.changes[retunes:]) \
                    and schedule.excluded_at(layer) == excluded:
                out[layer] = figures[column]
        return out

    def _estimates(self) -> np.ndarray | None:
        """Estimated seconds of every layer: the slicer's, or the calibrated guess, (layers,)."""
        return self._per_layer(0)

    def filament(self) -> tuple[float, float] | None:
        """Filament (mm) of the layers printed and of the whole job, or None (a G-code job,
        or before a layer is sliced).

        Each layer counts the slicer's figure when it was sliced in this run, else the
        geometry's guess with its own settings and bodies, calibrated on the layers
        sliced and sampled as the time is (a retune or a cancel moves the total at once).
        Worked out again only when one of these changed.
        """
        schedule = self.schedule
        if schedule is None:
            return None
        key = (len(schedule.estimates), len(self._samples), len(schedule.changes),
               tuple(schedule.cancelled), self._geometry is not None, self.last_done)
        cached = self._filament
        if cached is not None and cached[0] == key:
            return cached[1]
        per_layer = self._per_layer(1)
        figures = None
        if per_layer is not None:
            done = max(0, min(self.last_done + 1, self.layers))
            figures = (float(per_layer[:done].sum()), float(per_layer.sum()))
        self._filament = (key, figures)
        return figures

    def _per_layer(self, column: int) -> np.ndarray | None:
        """Every layer's estimated seconds (``column`` 0) or filament mm (1): the slicer's,
        or the calibrated guess, (layers,)."""
        if self.schedule is None:
            return None
        known = dict(self.schedule.estimates)
        if not known:
            return None
        out = np.full(self.layers, np.nan)
        for layer, figures in known.items():
            if 0 <= layer < self.layers:
                out[layer] = figures[column]
        missing = np.isnan(out)
        if not missing.any():
            return out
        if self._geometry is None:
            recent = out[~missing][-RECENT_LAYERS:]
            out[missing] = recent.mean()
            return out
        guess = self._guess(0, self.layers, column)
        sampled = self._valid_samples(column)
        sliced = np.flatnonzero(~missing)
        sampled.update(zip(sliced.tolist(), out[sliced].tolist(), strict=True))
        anchors = {k: (v, float(guess[k])) for k, v in sampled.items()}
        # past the latest retune only layers sliced with it count
        newest = max((f for f, _ in self.schedule.changes), default=0)
        if any(layer >= newest for layer in anchors):
            anchors = {k: v for k, v in anchors.items() if k >= newest}
        out[missing] = calibrated(guess, anchors)[missing]
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

    def _ending(self) -> float:
        """Estimated seconds of the end block (its lift)."""
        plan = self.schedule.base_plan
        settings = self.schedule.settings_at(self.layers - 1)
        top = plan.layer_z(self.layers - 1) if self.layers else 0.0
        return lift_time(min(END_LIFT, plan.bed[2] - top), settings.travel_speed,
                         settings.acceleration)

    def _backlog(self, estimates: np.ndarray) -> float:
        """Estimated seconds of the moves of the last layer done still in the printer's
        planner (its last :data:`PLANNER_BLOCKS` moves, as a share of the layer)."""
        lines = self.schedule.lines.get(self.last_done, 0)
        seconds = estimates[self.last_done]
        if lines <= 0 or np.isnan(seconds):
            return 0.0
        return float(seconds) * min(1.0, PLANNER_BLOCKS / lines)

    def remaining(self, now: float) -> float | None:
        """Seconds left, or None until a layer has been printed."""
        if self.started is None or self.last_done < self.first:
            return None
        now = self._active(now)
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
        left = (np.nansum(estimates[current:]) + self._ending() + self._backlog(estimates)) * pace
        in_layer = estimates[current] * pace if current < self.layers else 0.0
        return float(max(0.0, left - min(since, in_layer)))


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
