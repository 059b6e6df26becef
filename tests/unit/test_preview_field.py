"""`hostd preview --field`: the infill field drawn as a colour map under the toolpaths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hostd.app.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.mark.parametrize("field", ["linear", "poisson", "wave"])
def test_field_preview_paints_the_field(tmp_path: Path, field: str) -> None:
    plain, painted = tmp_path / "plain.png", tmp_path / "field.png"
    model = str(DATA / "dogbone_100x30x5.stl")
    args = ["preview", model, "--layer", "10", "--set", f"infill.field={field}"]
    assert main([*args, "-o", str(plain)]) == 0
    assert main([*args, "-o", str(painted), "--field"]) == 0
    plain_rgb = np.asarray(Image.open(plain).convert("RGB")).reshape(-1, 3)
    field_rgb = np.asarray(Image.open(painted).convert("RGB")).reshape(-1, 3)
    assert plain_rgb.shape == field_rgb.shape
    # the colour map adds many colours that the plain toolpath picture does not have
    assert len(np.unique(field_rgb, axis=0)) > len(np.unique(plain_rgb, axis=0)) + 50
