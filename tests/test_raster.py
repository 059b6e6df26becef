"""Thumbnail pictures drawn without an imaging library: coverage, borders, PNG read back."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from slicer.raster import Canvas

ORANGE, BROWN = (235, 120, 30, 255), (120, 55, 10, 255)


def test_rings_cover_the_pixels_whose_centres_are_inside() -> None:
    canvas = Canvas(10, 8)
    square = np.array([[2.0, 2.0], [6.0, 2.0], [6.0, 5.0], [2.0, 5.0], [2.0, 2.0]])
    triangle = np.array([[7.0, 0.0], [10.0, 0.0], [10.0, 3.0]])  # x >= 7 + y, clipped right
    rows, lo, hi = canvas.spans([square, triangle])
    runs = sorted(zip(rows.tolist(), lo.tolist(), hi.tolist(), strict=True))
    # square: centres 2.5..5.5 by 2.5..4.5; triangle: on row r, centres x >= 7.5 + r (a
    # centre on a left edge is inside, on a right edge outside)
    assert runs == [(0, 7, 10), (1, 8, 10), (2, 2, 6), (2, 9, 10), (3, 2, 6), (4, 2, 6)]


def test_painted_rings_have_a_border_and_read_back_as_png() -> None:
    canvas = Canvas(12, 10)
    canvas.polygons([np.array([[1.0, 1.0], [9.0, 1.0], [9.0, 8.0], [1.0, 8.0]])], ORANGE, BROWN)
    pixels = canvas.pixels
    assert tuple(pixels[4, 4]) == ORANGE  # inside
    assert tuple(pixels[1, 4]) == BROWN  # border row
    assert tuple(pixels[4, 1]) == BROWN  # border column
    assert tuple(pixels[0, 0]) == (0, 0, 0, 0)
    assert tuple(pixels[9, 11]) == (0, 0, 0, 0)
    small = canvas.halved()
    assert small.pixels.shape == (5, 6, 4)
    image = Image.open(io.BytesIO(small.png()))
    image.load()
    assert (image.format, image.mode, image.size) == ("PNG", "RGBA", (6, 5))
    assert np.array_equal(np.asarray(image), small.pixels)
    assert image.getchannel("A").getextrema() == (0, 255)
