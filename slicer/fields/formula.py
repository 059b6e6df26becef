"""The expression field: a user formula in x, y, z, layer and d, safely evaluated."""

from __future__ import annotations

import numpy as np

from slicer.expression import compile_formula
from slicer.fields.base import LayerContext, register
from slicer.fields.distance import signed_distance
from slicer.fields.grid import GridField
from slicer.settings import SliceSettings

VARIABLES = ("x", "y", "z", "layer", "d")


@register("expression")
class ExpressionField(GridField):
    """H = ``infill.expression``, e.g. ``sin(x / 3) * 4 + y`` or ``d + 0.2 * sin(x)``.

    Variables: ``x``, ``y`` mm from the model's lower-left corner (so a formula
    does not depend on where the part sits on the bed), ``z`` the layer's height
    mm, ``layer`` its index, ``d`` mm inside the layer outline (the paper's
    H_pr: negative outside). A bad formula is refused when the field is built,
    as ``SettingsError("infill.expression", reason)``.
    """

    name = "expression"
    gap = 3.0

    def __init__(self, settings: SliceSettings) -> None:
        super().__init__(settings)
        self.formula = compile_formula(settings.infill_expression, VARIABLES)

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values: ``x``, ``y`` (n,) float64 mm -> (n,) float64, NaN where undefined."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        variables: dict[str, np.ndarray | float] = {
            "x": x - ctx.bounds[0],
            "y": y - ctx.bounds[1],
            "z": float(ctx.z),
            "layer": float(ctx.index),
        }
        if "d" in self.formula.names:
            variables["d"] = signed_distance(ctx.domain, x, y, step=self.settings.line_width / 8.0)
        values = np.broadcast_to(self.formula(variables), x.shape).astype(float)
        return np.where(np.isfinite(values), values, np.nan)
