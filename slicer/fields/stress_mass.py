"""Equal mass: the infill density (Eq. 14's k) at which a part weighs what a reference does."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

from slicer.gcode import filament_grams
from slicer.plan import SlicePlan
from slicer.settings import SettingsError

TOLERANCE = 0.005  # relative mass error the search stops at (the promise is 1 %)
MAX_TRIALS = 8


@dataclass(frozen=True)
class MassMatch:
    """The outcome of :func:`match_mass`: ``k`` the infill density found, ``mass_g`` the
    part's extruded mass there, ``target_g`` the mass asked for, ``reference`` what it
    is the mass of, ``trials`` whole-part slicings it took."""

    k: float
    mass_g: float
    target_g: float
    reference: str
    trials: int

    @property
    def error(self) -> float:
        """Relative mass error, (mass - target) / target."""
        return (self.mass_g - self.target_g) / self.target_g

    def describe(self) -> str:
        """One line for the summary."""
        return (
            f"equal mass: k = {self.k:.4f} (infill.density), {self.mass_g:.3f} g against "
            f"{self.target_g:.3f} g ({self.reference}), {100 * self.error:+.2f} %"
        )


def extruded_grams(plan: SlicePlan) -> float:
    """The mass of filament the whole program extrudes, g (every layer sliced)."""
    millimetres = sum(plan.layer_code(i).filament_mm for i in range(plan.layer_count))
    return filament_grams(millimetres, plan.settings)


def target_of(plan: SlicePlan) -> tuple[float, str] | None:
    """The mass the settings ask for, g, and what it is: ``infill.target_mass_g``, or
    linear infill at the job's density for ``infill.match_mass_of = "linear"``;
    None when neither is set."""
    settings = plan.settings
    if settings.infill_target_mass_g > 0 and settings.infill_match_mass_of:
        raise SettingsError(
            "infill.target_mass_g", "give either it or infill.match_mass_of, not both"
        )
    if settings.infill_target_mass_g > 0:
        return settings.infill_target_mass_g, "infill.target_mass_g"
    if settings.infill_match_mass_of == "linear":
        linear = plan.with_settings(dataclasses.replace(settings, infill_field="linear"))
        return extruded_grams(linear), f"linear infill at density {settings.infill_density:g}"
    return None


def match_mass(
    plan: SlicePlan, measure: Callable[[SlicePlan], float] = extruded_grams
) -> tuple[SlicePlan, MassMatch | None]:
    """The plan at the infill density whose extruded mass is the target's within 1 %.

    ``measure`` gives a plan's extruded mass in g (by default every layer is
    sliced here; a caller writing the G-code anyway may measure by writing it).
    Mass grows with density; the search starts at the settings' density (the
    stress field's levels are fitted to the same mean spacing as the linear
    field's, so this is often within 1 % already), brackets the target between
    density 0 (walls and skins only) and 1 and closes in by secant steps. Raises
    SettingsError when the target lies outside what the part can weigh.
    """
    wanted = target_of(plan)
    if wanted is None:
        return plan, None
    target, reference = wanted
    settings = plan.settings
    trials = 0

    def mass_at(density: float) -> tuple[SlicePlan, float]:
        nonlocal trials
        trials += 1
        trial = plan.with_settings(dataclasses.replace(settings, infill_density=density))
        return trial, measure(trial)

    first_d = settings.infill_density
    first_plan, first_m = mass_at(first_d)
    if abs(first_m - target) <= TOLERANCE * target:
        return first_plan, MassMatch(first_d, first_m, target, reference, trials)
    if first_m > target:
        high_d, high_plan, high_m = first_d, first_plan, first_m
        low_d, (low_plan, low_m) = 0.0, mass_at(0.0)
        if target < low_m * (1.0 - TOLERANCE):
            raise SettingsError(
                "infill.target_mass_g",
                f"{target:.2f} g is less than the walls and skins alone ({low_m:.2f} g)",
            )
    else:
        low_d, low_plan, low_m = first_d, first_plan, first_m
        high_d = min(1.0, max(2.0 * first_d, 0.05))
        high_plan, high_m = mass_at(high_d)
        while high_m < target and high_d < 1.0:
            low_d, low_plan, low_m = high_d, high_plan, high_m
            high_d = min(1.0, 2.0 * high_d)
            high_plan, high_m = mass_at(high_d)
        if high_m < target * (1.0 - TOLERANCE):
            raise SettingsError(
                "infill.target_mass_g",
                f"{target:.2f} g is more than the part solid ({high_m:.2f} g)",
            )
    best = min(((low_d, low_plan, low_m), (high_d, high_plan, high_m)),
               key=lambda t: abs(t[2] - target))
    while abs(best[2] - target) > TOLERANCE * target and trials < MAX_TRIALS:
        span = high_m - low_m
        density = low_d + (target - low_m) * (high_d - low_d) / span if span > 0 else high_d
        density = min(max(density, low_d + 0.05 * (high_d - low_d)),
                      high_d - 0.05 * (high_d - low_d))
        trial_plan, mass = mass_at(density)
        if mass < target:
            low_d, low_plan, low_m = density, trial_plan, mass
        else:
            high_d, high_plan, high_m = density, trial_plan, mass
        if abs(mass - target) < abs(best[2] - target):
            best = (density, trial_plan, mass)
    density, chosen, mass = best
    return chosen, MassMatch(density, mass, target, reference, trials)
