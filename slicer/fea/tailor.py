"""Slicing with the built-in analysis: a load case turns a plan's infill into stress infill."""

from __future__ import annotations

import dataclasses
import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from slicer.fea.loadcase import load_path_for
from slicer.fields.stress_mass import MassMatch, extruded_grams, match_mass
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

if TYPE_CHECKING:
    from slicer.fea.field import FieldFile


# analyses run beside the first layers of a print (one at a time)
_BACKGROUND = ThreadPoolExecutor(max_workers=1, thread_name_prefix="fea")


@dataclass(frozen=True)
class Tailoring:
    """What was done to a plan: the analysis (``field``, None without a load case, or
    ``running`` while it runs beside the first layers) and the equal-mass search
    (``mass``, None unless asked for)."""

    field: FieldFile | None
    mass: MassMatch | None
    running: Future[FieldFile] | None = None

    def lines(self) -> list[str]:
        """Summary lines, one fact each (an analysis still running is reported so)."""
        out: list[str] = []
        field = self.field
        if field is None and self.running is not None:
            if not self.running.done():
                return ["stress analysis: running beside the first layers"]
            field = self.running.result() if self.running.exception() is None else None
        if field is not None:
            f = field
            how = "cached" if f.cached else f"analysed in {f.seconds:.1f} s"
            cell = " x ".join(f"{c:.2f}" for c in f.cell)
            if f.path.name.startswith("optimal"):
                from slicer.fea.optimal import ITERATIONS

                out.append(f"optimised density: {f.elements} elements of {cell} mm, "
                           f"{1 + ITERATIONS} analyses ({how})")
            else:
                out.append(
                    f"stress analysis: {f.elements} elements of {cell} mm, peak von Mises "
                    f"{f.peak_mpa:.2f} MPa ({how})"
                )
        if self.mass is not None:
            out.append(self.mass.describe())
        return out


def find_load_case(model: str | os.PathLike[str], settings: SliceSettings,
                   given: str | os.PathLike[str] | None = None) -> Path | None:
    """The load case of a model: ``given``, else ``infill.load``, else ``NAME.load.toml``
    beside the model when it exists; None when there is none."""
    if given:
        return Path(given)
    if settings.infill_load:
        return Path(settings.infill_load)
    beside = load_path_for(model)
    return beside if beside.is_file() else None


def with_analysis(
    model: str | os.PathLike[str],
    settings: SliceSettings,
    load: str | os.PathLike[str],
    cache_dir: str | os.PathLike[str],
) -> tuple[SliceSettings, FieldFile]:
    """Settings whose infill is the stress field of ``model`` under the case ``load``
    (``infill.field = "stress"``, ``infill.file`` the analysis' field file in
    ``cache_dir``, analysed there unless cached). Raises LoadCaseError, ModelError."""
    from slicer.fea.field import stress_field_file  # scipy.sparse: loaded when needed

    field = stress_field_file(
        model, load, cache_dir, settings.fea_mesh_size,
        settings.fea_youngs_modulus_mpa, settings.fea_poisson_ratio, optimal_volume(settings),
    )
    changed = dataclasses.replace(
        settings, infill_field="stress", infill_file=str(field.path), infill_load=str(load)
    )
    return changed, field


def tailored_plan(
    model: str | os.PathLike[str],
    settings: SliceSettings,
    bed: tuple[float, float, float],
    cache_dir: str | os.PathLike[str],
    load: str | os.PathLike[str] | None = None,
    measure: Callable[[SlicePlan], float] = extruded_grams,
    background: bool = False,
    hold: threading.Event | None = None,
) -> tuple[SlicePlan, Tailoring]:
    """The model's plan with the analysis applied (when it has a load case, see
    :func:`find_load_case`) and its mass matched (when the settings ask; ``measure``
    as in :func:`slicer.fields.stress_mass.match_mass`).

    With ``background`` (and no equal mass asked, which needs the field to slice
    every layer), an analysis not cached yet runs on a worker thread and the plan
    is returned at once: layers without sparse infill (the bottom skins) slice
    without it, and the first layer that needs the field waits for it. With
    ``hold``, that analysis begins only once ``hold`` is set (by the caller, or by
    the first layer that waits for the field): the first layers are not slowed
    by it.
    """
    field = None
    case = find_load_case(model, settings, load)
    if case is not None and background and not _wants_mass(settings):
        from slicer.fea.field import field_path, read_field_file
        from slicer.fields import stress_pending

        optimal = optimal_volume(settings)
        path, loadcase, vertices, faces, size = field_path(
            model, case, cache_dir, settings.fea_mesh_size,
            settings.fea_youngs_modulus_mpa, settings.fea_poisson_ratio, optimal)
        settings = dataclasses.replace(
            settings, infill_field="stress", infill_file=str(path), infill_load=str(case))
        if path.is_file():
            return SlicePlan.from_file(model, settings, bed), Tailoring(read_field_file(path), None)
        if hold is not None:
            stress_pending.hold(path, hold)
        running = _BACKGROUND.submit(_solve_when_released, hold, path, loadcase, vertices,
                                     faces, size, optimal)
        stress_pending.announce(path, running)
        return SlicePlan.from_file(model, settings, bed), Tailoring(None, None, running)
    if case is not None:
        settings, field = with_analysis(model, settings, case, cache_dir)
    plan = SlicePlan.from_file(model, settings, bed)
    plan, mass = match_mass(plan, measure)
    return plan, Tailoring(field, mass)


def _solve_when_released(hold: threading.Event | None, *args: object) -> FieldFile:
    """:func:`slicer.fea.field.solve_field` once ``hold`` (if any) is set."""
    if hold is not None:
        hold.wait()
    from slicer.fea.field import solve_field

    return solve_field(*args)  # type: ignore[arg-type]


def optimal_volume(settings: SliceSettings) -> float:
    """The mean density an ``infill.stress = "optimal"`` field is optimised at (the
    job's infill density, at least 0.1), or 0 for the stress itself."""
    if settings.infill_stress != "optimal":
        return 0.0
    return max(settings.infill_density, 0.1)


def _wants_mass(settings: SliceSettings) -> bool:
    return bool(settings.infill_match_mass_of) or settings.infill_target_mass_g > 0


def default_cache_dir() -> Path:
    """Where the command line keeps analyses: ``$XDG_CACHE_HOME/hostd/fea``."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "hostd" / "fea"
