"""`hostd preview`: a PNG with walls, infill and skin in their own colours."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image
from support.slicer_helpers import DATA

from slicer.output.preview import COLOURS

HOSTD = [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]


def _has_colour(pixels: np.ndarray, colour) -> bool:
    return bool((np.abs(pixels.astype(int) - np.array(colour)).sum(axis=2) < 10).any())


def test_preview_draws_each_kind(tmp_path) -> None:
    out = tmp_path / "p.png"
    run = subprocess.run(
        [*HOSTD, "preview", str(DATA / "cube20_xyz.stl"), "--layer", "50", "-o", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    pixels = np.asarray(Image.open(out).convert("RGB"))
    for kind in ("WALL-OUTER", "WALL-INNER", "FILL"):
        assert _has_colour(pixels[:, 150:], COLOURS[kind]), kind  # right of the legend
    top = tmp_path / "top.png"
    subprocess.run(
        [*HOSTD, "preview", str(DATA / "cube20_xyz.stl"), "--layer", "99", "-o", str(top)],
        check=True,
        capture_output=True,
    )
    pixels = np.asarray(Image.open(top).convert("RGB"))
    assert _has_colour(pixels[:, 150:], COLOURS["SKIN"])
    assert not _has_colour(pixels[:, 150:], COLOURS["FILL"])


def test_preview_refuses_a_layer_out_of_range(tmp_path) -> None:
    run = subprocess.run(
        [
            *HOSTD,
            "preview",
            str(DATA / "cube20_xyz.stl"),
            "--layer",
            "500",
            "-o",
            str(tmp_path / "x.png"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 2
    assert "layers 1..100" in run.stderr


@pytest.mark.parametrize(("asked", "shown"), [("1", 1), ("50", 50), ("-1", 100)])
def test_preview_and_its_picture_say_the_same_layer_n_of_m(tmp_path, asked, shown) -> None:
    out = tmp_path / "p.png"
    run = subprocess.run(
        [*HOSTD, "preview", str(DATA / "cube20_xyz.stl"), "--layer", asked, "-o", str(out)],
        capture_output=True, text=True, check=False,
    )
    assert run.returncode == 0, run.stderr
    said = re.search(r"layer (\d+) of (\d+)", run.stdout)
    assert said is not None, run.stdout
    assert (int(said[1]), int(said[2])) == (shown, 100)
    title = Image.open(out).text["Title"]  # the title drawn on the picture, as text
    assert title.startswith(f"layer {shown} of 100  z=")
    assert f";LAYER:{shown - 1} " in run.stdout  # the G-code's comment counts from 0
