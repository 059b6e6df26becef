"""Built-in linear elastic analysis on voxel hexahedra (scikit-fem), for stress-driven infill."""

from __future__ import annotations

import os
from pathlib import Path

LOAD_SUFFIX = ".load.toml"


def load_path_for(model: str | os.PathLike[str]) -> Path:
    """``NAME.load.toml`` beside ``NAME.stl`` (here, not in :mod:`slicer.fea.loadcase`, so
    that a plain slice looks for it without importing the analysis)."""
    model = Path(model)
    return model.with_name(model.stem + LOAD_SUFFIX)
