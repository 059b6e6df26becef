"""The infill field interface and the registry of fields by name."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import shapely

from slicer.settings import SliceSettings


@dataclass(frozen=True)
class LayerContext:
    """What a field may know about the layer it fills.

    ``domain`` is the layer's whole solid region (the outline, before walls);
    ``index`` the layer number from 0; ``z`` the layer's top height in mm;
    ``bounds`` the placed model's (xmin, ymin, xmax, ymax) in mm, the same for
    every layer so fields line up from layer to layer.
    """

    index: int
    z: float
    domain: shapely.Geometry
    bounds: tuple[float, float, float, float]
    settings: SliceSettings


class InfillField(Protocol):
    """A scalar field H(x, y) on one layer and the levels c_k whose sets are toolpaths."""

    name: str

    def paths(
        self, region: shapely.Geometry, ctx: LayerContext, spacing: float
    ) -> shapely.Geometry:
        """Infill toolpaths: level sets of the field clipped to ``region``.

        ``region`` is the contracted domain w' (inside the innermost wall plus
        overlap); ``spacing`` the mean distance between neighbouring paths in mm
        that the density asks for. Returns a (Multi)LineString, possibly empty.
        """
        ...

    def sample(self, x: np.ndarray, y: np.ndarray, ctx: LayerContext) -> np.ndarray:
        """Field values at points: ``x``, ``y`` (n,) float64 mm -> (n,) float64."""
        ...


FieldFactory = Callable[[SliceSettings], InfillField]
FIELDS: dict[str, FieldFactory] = {}
# fields whose module registers them alone, without the whole library's imports (a
# stress job's first layers should not wait for scipy.spatial and scipy.interpolate)
_OWN_MODULE = {"stress": "slicer.fields.stress"}


def register(name: str) -> Callable[[FieldFactory], FieldFactory]:
    """Class decorator: make a field available as ``infill.field = name``."""

    def decorate(factory: FieldFactory) -> FieldFactory:
        FIELDS[name] = factory
        return factory

    return decorate


def get_field(settings: SliceSettings) -> InfillField:
    """The field strategy the settings select (``infill.field``).

    The library (every built-in field, and the heavier libraries some of them
    need) is imported only when the field asked for is not registered yet, so
    the default linear field starts fast.
    """
    if settings.infill_field in _OWN_MODULE and settings.infill_field not in FIELDS:
        import importlib

        importlib.import_module(_OWN_MODULE[settings.infill_field])
    if settings.infill_field not in FIELDS:
        import slicer.fields.library  # noqa: F401  (registers the built-in fields)

    try:
        factory = FIELDS[settings.infill_field]
    except KeyError:
        raise ValueError(f"infill.field: no field named {settings.infill_field!r}") from None
    return factory(settings)
