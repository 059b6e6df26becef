"""Imports every built-in field module so that each registers itself by name."""

from slicer.fields import (
    concentric,  # noqa: F401
    eggcrate,  # noqa: F401
    formula,  # noqa: F401
    linear,  # noqa: F401
    poisson,  # noqa: F401
    random_cells,  # noqa: F401
    stress,  # noqa: F401
    wave,  # noqa: F401
)
