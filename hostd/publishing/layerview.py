"""One layer as the dashboard draws it: toolpaths as simplified polylines, bodies, field samples.

Served by the ``layer`` and ``estimate`` requests of the control socket and of
MQTT (see :mod:`hostd.api` for the reply's fields). Everything here reads the
job's schedule (the same plans and excluded bodies that slice the layer for the
printer) and never changes it.
"""

from __future__ import annotations

import math
import re
import weakref
from typing import Any

import numpy as np
import shapely

from drivers.link.protocol import strip_comment
from hostd.jobs.schedule import LayerSchedule
from slicer.settings import INFILL_FIELDS, SliceSettings

MAX_FIELD_CELLS = 40_000  # field samples per reply (e.g. 200 x 200)
MAX_BODIES = 64  # bodies outlined per reply
ESTIMATE_SAMPLES = 8  # layers of a job sliced (once) for its filament estimate
_AXIS = re.compile(r"([XYE])(-?\d+(?:\.\d*)?)")


def parse_layer(lines: list[str]) -> tuple[list[tuple[str, np.ndarray, int]], int]:
    """Extruding polylines of one layer's G-code, and the layer's command count.

    Returns ``(paths, commands)``: each path is ``(kind, coords, end)`` with
    ``kind`` the ``;TYPE:`` name, ``coords`` (k, 2) float64 mm and ``end`` the
    number of the layer's commands sent once the path is finished (1-based
    count of non-comment lines up to its last move). Moves without extrusion
    end a path.
    """
    paths: list[tuple[str, np.ndarray, int]] = []
    kind = "UNKNOWN"
    x = y = 0.0
    current: list[tuple[float, float]] = []
    commands = 0
    end = 0

    def close() -> None:
        if len(current) >= 2:
            paths.append((kind, np.asarray(current, dtype=float), end))
        current.clear()

    for line in lines:
        if line.startswith(";TYPE:"):
            close()
            kind = line[6:].strip()
            continue
        command = strip_comment(line)
        if not command:
            continue
        commands += 1
        if not (command.startswith("G1") or command.startswith("G0")):
            continue
        axes = dict(_AXIS.findall(command))
        nx = float(axes.get("X", x))
        ny = float(axes.get("Y", y))
        extruding = command.startswith("G1") and float(axes.get("E", 0.0)) > 0
        if (nx, ny) != (x, y):
            if extruding:
                if not current:
                    current.append((x, y))
                current.append((nx, ny))
                end = commands
            else:
                close()
        x, y = nx, ny
    close()
    return paths, commands


def simplified(coords: np.ndarray, tolerance: float) -> list[list[float]]:
    """A polyline simplified to ``tolerance`` mm, as ``[[x, y], ...]`` rounded to 0.01 mm."""
    if tolerance > 0 and len(coords) > 2:
        line = shapely.simplify(shapely.linestrings(coords), tolerance, preserve_topology=False)
        coords = shapely.get_coordinates(line)
    return np.round(coords, 2).tolist()


def _rings(geometry: shapely.Geometry, tolerance: float) -> list[list[list[float]]]:
    """Every exterior and interior ring of ``geometry``, simplified."""
    rings = shapely.get_rings(shapely.get_parts(geometry))
    if tolerance > 0:
        rings = shapely.simplify(rings, tolerance)
    return [np.round(shapely.get_coordinates(ring), 2).tolist() for ring in rings]


def layer_view(
    schedule: LayerSchedule,
    index: int,
    tolerance: float = 0.2,
    field: tuple[int, int] | None = None,
    lines: list[str] | None = None,
) -> dict[str, Any]:
    """The reply of the ``layer`` command for layer ``index`` of a sliced job.

    ``tolerance`` (mm) simplifies polylines and outlines; ``field`` = (columns,
    rows) adds the infill field sampled on that grid over the model's bounds.
    ``lines`` is the layer's G-code when the daemon holds it already (streamed or
    made ahead: :meth:`hostd.printing.sources.SlicedSource.held`); otherwise the layer is
    sliced again for the view (:meth:`LayerSchedule.layer_preview`), which leaves the
    schedule as it was. Either way nothing the printer streams changes.
    """
    plan = schedule.plan_at(index)
    excluded = schedule.excluded_at(index)
    paths, commands = parse_layer(lines if lines is not None else schedule.layer_preview(index))
    count = int(plan.body_count)
    bodies = []
    if count > 1:
        for body in range(min(count, MAX_BODIES)):
            others = frozenset(range(count)) - {body}
            outline = schedule.base_plan.outline(index, others)
            bodies.append({
                "index": body,
                "cancelled": body in excluded,
                "rings": [] if outline.is_empty else _rings(outline, tolerance),
            })
    reply: dict[str, Any] = {
        "layer": index,
        "layers": schedule.layer_count,
        "z": round(float(plan.layer_z(index)), 3),
        "bounds": [round(float(v), 2) for v in plan.bounds],
        "commands": commands,
        "paths": [
            {"kind": kind, "end": end, "points": simplified(coords, tolerance)}
            for kind, coords, end in paths
        ],
        "body_count": count,
        "bodies": bodies,
        "cancelled": [{"object": body, "from_layer": first} for body, first in schedule.cancelled],
        "field": field_samples(schedule, index, *field) if field else None,
    }
    return reply


def field_samples(schedule: LayerSchedule, index: int, columns: int, rows: int) -> dict[str, Any]:
    """The infill field over the model's bounds: ``values`` rows (top first) of 0..255, -1 outside.

    Values are scaled to the 1st..99th percentile of the samples inside the layer.
    """
    columns, rows = max(1, int(columns)), max(1, int(rows))
    if columns * rows > MAX_FIELD_CELLS:
        scale = math.sqrt(MAX_FIELD_CELLS / (columns * rows))
        columns, rows = max(1, int(columns * scale)), max(1, int(rows * scale))
    plan = schedule.plan_at(index)
    xmin, ymin, xmax, ymax = plan.bounds
    xs = xmin + (np.arange(columns) + 0.5) * (xmax - xmin) / columns
    ys = ymax - (np.arange(rows) + 0.5) * (ymax - ymin) / rows
    gx, gy = np.meshgrid(xs, ys)
    ctx = plan.layer_context(index, schedule.excluded_at(index))
    out = np.full(gx.shape, -1, dtype=np.int64)
    low = high = 0.0
    if not ctx.domain.is_empty:
        inside = shapely.contains_xy(ctx.domain, gx.ravel(), gy.ravel()).reshape(gx.shape)
        if inside.any():
            values = np.asarray(plan.infill_field.sample(gx[inside], gy[inside], ctx), float)
            finite = np.isfinite(values)
            if finite.any():
                low, high = (float(v) for v in np.percentile(values[finite], [1.0, 99.0]))
                span = high - low if high > low else 1.0
                scaled = np.clip((np.nan_to_num(values, nan=low) - low) / span, 0.0, 1.0)
                out[inside] = np.round(scaled * 255).astype(np.int64)
    return {
        "name": str(plan.settings.infill_field),
        "columns": columns,
        "rows": rows,
        "low": round(low, 4),
        "high": round(high, 4),
        "values": out.tolist(),
    }


def retunable(settings: SliceSettings) -> dict[str, Any]:
    """The settings the dashboard offers to retune, by flat key."""
    return {
        "infill.density": settings.infill_density,
        "infill.field": settings.infill_field,
        "nozzle_temp": settings.nozzle_temp,
        "bed_temp": settings.bed_temp,
    }


def sample_layers(count: int) -> list[int]:
    """The layers an estimate slices: ESTIMATE_SAMPLES spread evenly over the job, fixed."""
    if count <= 0:
        return []
    picks = np.linspace(0, count - 1, num=min(ESTIMATE_SAMPLES, count))
    return sorted({round(float(v)) for v in picks})


_MEASURED: weakref.WeakKeyDictionary[LayerSchedule, dict[tuple, tuple[float, float]]] = (
    weakref.WeakKeyDictionary()
)


def _measure(schedule: LayerSchedule, index: int, settings: SliceSettings,
             excluded: frozenset[int], plans: dict[SliceSettings, Any]) -> tuple[float, float]:
    """Filament (mm) and time (s) of one layer sliced with ``settings``, remembered per job."""
    seen = _MEASURED.setdefault(schedule, {})
    key = (index, settings, excluded)
    if key not in seen:
        plan = plans.get(settings)
        if plan is None:
            plan = plans[settings] = schedule.base_plan.with_settings(settings)
        code = plan.layer_code(index, excluded)
        seen[key] = (code.filament_mm, code.time_s)
    return seen[key]


def estimate(
    schedule: LayerSchedule,
    current: int,
    next_unsliced: int,
    eta_s: float | None,
    changes: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The job's filament (used, total) and, with ``changes``, a retune's effect on it and the ETA.

    The same few layers spread over the job (:func:`sample_layers`) are sliced
    once per settings and remembered: their mean filament per layer before
    ``current`` (the layer printing) and from it on, times the layer counts,
    give the estimates. With ``changes`` (flat keys, checked as ``set`` checks
    them: SettingsError when refused) the sampled layers from ``next_unsliced``
    on are measured with them too; the ratio of the remaining times scales
    ``eta_s``. Nothing is recorded.
    """
    layers = schedule.layer_count
    current = max(0, min(current, layers))
    picks = sample_layers(layers)
    plans: dict[SliceSettings, Any] = {schedule.settings_at(i): schedule.plan_at(i) for i in picks}
    if changes:
        probe = SliceSettings.from_mapping(changes, base=schedule.settings_at(layers - 1))
        schedule.base_plan.with_settings(probe)  # refuses geometry changes

    def measured(index: int, retuned: bool) -> tuple[float, float]:
        settings = schedule.settings_at(index)
        if retuned and index >= next_unsliced:
            settings = SliceSettings.from_mapping(changes or {}, base=settings)
        return _measure(schedule, index, settings, schedule.excluded_at(index), plans)

    def per_layer(indices: list[int], retuned: bool) -> tuple[float, float]:
        if not indices:
            return 0.0, 0.0
        values = np.array([measured(i, retuned) for i in indices])
        return float(values[:, 0].mean()), float(values[:, 1].mean())

    before = [i for i in picks if i < current] or picks
    after = [i for i in picks if i >= current] or picks[-1:]
    used = per_layer(before, False)[0] * current
    left = layers - current
    now_mm, now_s = per_layer(after, False)
    reply: dict[str, Any] = {
        "layer": current,
        "from_layer": next_unsliced,
        "sampled_layers": picks,
        "filament_used_mm": round(used, 1),
        "filament_total_mm": round(used + now_mm * left, 1),
        "eta_s": eta_s,
        "settings": retunable(schedule.settings_at(min(next_unsliced, layers - 1))),
        "fields": list(INFILL_FIELDS),
    }
    if changes:
        late = [i for i in picks if i >= next_unsliced] or picks[-1:]
        old_mm, old_s = per_layer(late, False)
        new_mm, new_s = per_layer(late, True)
        unsliced = layers - next_unsliced
        ratio = (now_s * left + (new_s - old_s) * unsliced) / (now_s * left) if now_s else 1.0
        reply["retuned"] = {
            "filament_total_mm": round(used + now_mm * left + (new_mm - old_mm) * unsliced, 1),
            "eta_s": None if eta_s is None else round(eta_s * ratio, 1),
            "time_ratio": round(ratio, 4),
        }
    return reply


def _commands(lines: list[str]) -> int:
    return sum(1 for line in lines if strip_comment(line))


def acked_before(schedule: LayerSchedule, runner: Any, source: Any, stored: Any, index: int
                 ) -> int | None:
    """Job lines acknowledged when layer ``index`` started streaming, when that is known.

    ``stored`` is the job as the store has it (its ``layer`` is the last completed
    one, ``lines_acked`` counted then). None for a layer that has not started, or
    whose start was before a checkpoint this run cannot see.
    """
    if runner is None or index > runner.completed + 1:
        return None
    if index == runner.first:
        before = stored.lines_acked if index > 0 and stored.layer == index - 1 else 0
        return before + _commands(source.preamble())
    if stored.layer == index - 1:
        return int(stored.lines_acked)
    return None
