"""Equal mass: the infill density (Eq. 14's k) at which a part weighs what a reference does."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from dataclasses import dataclass

from slicer.output.gcode import filament_grams
from slicer.plan import SlicePlan
from slicer.settings import SettingsError

TOLERANCE = 0.005  # relative mass error the search stops at (the promise is 1 %)
MAX_TRIALS = 8  # densities tried to bracket the target, and as many to close in


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
    The mass need not rise with the density: a stress field's lines can thin out
    as ``k`` rises (more of the part falls under the level placement's least
    spacing). The search starts at the settings' density (the stress field's
    levels are fitted to the same mean spacing as the linear field's, so this is
    often within 1 % already), then tries density 0 (walls and skins only) or 1,
    the other, then the middles of the widest gaps between densities tried, until
    two neighbours lie on either side of the target; it closes in between them by
    false position, keeping the side on which each trial falls. Raises
    SettingsError, saying why, when no density reaches the target: less than the
    walls and skins alone, or more than the most this infill weighs (at the
    density where it weighed most, beside the part printed solid).
    """
    wanted = target_of(plan)
    if wanted is None:
        return plan, None
    target, reference = wanted
    settings = plan.settings
    tried: dict[float, tuple[SlicePlan, float]] = {}

    def mass_at(density: float) -> float:
        trial = plan.with_settings(dataclasses.replace(settings, infill_density=density))
        tried[density] = (trial, measure(trial))
        return tried[density][1]

    def close(density: float) -> bool:
        return abs(tried[density][1] - target) <= TOLERANCE * target

    def done(density: float) -> tuple[SlicePlan, MassMatch]:
        chosen, mass = tried[density]
        return chosen, MassMatch(density, mass, target, reference, len(tried))

    def nearest() -> float:
        return min(tried, key=lambda d: abs(tried[d][1] - target))

    first = settings.infill_density
    ends = [0.0, 1.0] if mass_at(first) > target else [1.0, 0.0]
    bracket = None
    for step in range(MAX_TRIALS):
        if close(nearest()):
            return done(nearest())
        bracket = _bracket(tried, target)
        walls_too_heavy = 0.0 in tried and target < tried[0.0][1] * (1.0 - TOLERANCE)
        if bracket is not None or walls_too_heavy or step == MAX_TRIALS - 1:
            break
        density = next((d for d in ends if d not in tried), -1.0)
        if density < 0:  # the middle of the widest gap between densities tried
            keys = sorted(tried)
            gap = max(range(len(keys) - 1), key=lambda i: keys[i + 1] - keys[i])
            density = 0.5 * (keys[gap] + keys[gap + 1])
        mass_at(density)
    if bracket is None:
        raise _unreachable(plan, tried, target, measure)
    low, high = bracket
    while len(tried) < 2 * MAX_TRIALS:
        if close(nearest()):
            return done(nearest())
        m_low, m_high = tried[low][1], tried[high][1]
        span = m_high - m_low
        density = low + (target - m_low) * (high - low) / span if span else 0.5 * (low + high)
        density = min(max(density, low + 0.05 * (high - low)), high - 0.05 * (high - low))
        mass = mass_at(density)
        if (mass - target) * (m_low - target) > 0:
            low = density
        else:
            high = density
    return done(nearest())


def _bracket(tried: dict[float, tuple[SlicePlan, float]], target: float
             ) -> tuple[float, float] | None:
    """Two neighbouring densities tried whose masses lie on either side of ``target``
    (the pair nearest the target's side changes first, by density), or None."""
    keys = sorted(tried)
    for a, b in itertools.pairwise(keys):
        if (tried[a][1] - target) * (tried[b][1] - target) <= 0:
            return a, b
    return None


def _unreachable(plan: SlicePlan, tried: dict[float, tuple[SlicePlan, float]], target: float,
                 measure: Callable[[SlicePlan], float]) -> SettingsError:
    """Why no density reaches ``target``: the lightest and heaviest masses tried, and the
    part printed solid (linear infill at density 1) for comparison."""
    lightest = min(tried, key=lambda d: tried[d][1])
    heaviest = max(tried, key=lambda d: tried[d][1])
    if target < tried[lightest][1]:
        walls = tried.get(0.0, tried[lightest])[1]
        return SettingsError(
            "infill.target_mass_g",
            f"{target:.2f} g is less than the walls and skins alone ({walls:.2f} g)",
        )
    solid = plan.with_settings(dataclasses.replace(plan.settings, infill_field="linear",
                                                   infill_density=1.0))
    return SettingsError(
        "infill.target_mass_g",
        f"{target:.2f} g is more than this infill weighs at any density: at most "
        f"{tried[heaviest][1]:.2f} g (k = {heaviest:.3g}; the part printed solid weighs "
        f"{measure(solid):.2f} g)",
    )
