"""Thumbnail pictures drawn without an imaging library: coverage, borders, PNG read back."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

from slicer.geometry.raster import Canvas

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


def _mean_of_blocks(pixels: np.ndarray) -> np.ndarray:
    """Each 2 x 2 block's alpha-weighted mean colour and mean alpha, rounded: the halving
    rule computed over every block the plain way."""
    h, w = pixels.shape[0] // 2, pixels.shape[1] // 2
    p = pixels[: 2 * h, : 2 * w].astype(np.int64).reshape(h, 2, w, 2, 4)
    alpha = p[..., 3:4]
    weight = alpha.sum(axis=(1, 3)).astype(np.float64)
    colour = (p[..., :3] * alpha).sum(axis=(1, 3)) / np.maximum(weight, 1.0)
    return np.rint(np.concatenate([colour, weight / 4.0], axis=-1)).astype(np.uint8)


def test_packed_layers_and_halving_match_the_plain_rules() -> None:
    rng = np.random.default_rng(3)
    rings = [[rng.uniform(-5, 45, (int(rng.integers(3, 9)), 2)) for _ in range(3)]
             for _ in range(6)]
    rings[2] = []  # a layer with nothing to draw
    rings[4].append(np.array([[1.0, 1.0], [30.0, 2.0]]))  # too short to be a ring
    fills = [(200, 40 * k, 10, 255 if k % 2 else 128) for k in range(6)]
    edges = [(10 * k, 90, 0, 255 if k % 3 else 0) for k in range(6)]
    plain, packed = Canvas(41, 33), Canvas(41, 33)
    plain.layers(rings, fills, edges)
    points = np.concatenate([r for group in rings for r in group])
    sizes = [len(r) for group in rings for r in group]
    ring_of = np.repeat(np.arange(len(sizes)), sizes)
    group_of = np.repeat(np.arange(len(rings)), [len(group) for group in rings])
    packed.packed_layers(points, ring_of, group_of, fills, edges)
    assert np.array_equal(plain.pixels, packed.pixels)
    assert len(np.unique(plain.index)) >= 5  # several layers show
    small = packed.halved().pixels
    assert small.shape == (16, 20, 4)
    assert np.array_equal(small, _mean_of_blocks(packed.pixels))
    blocks = packed.index[:32, :40].reshape(16, 2, 20, 2)
    mixed = (blocks != blocks[:, :1, :, :1]).any(axis=(1, 3))
    assert mixed.any()
    assert (~mixed).any()
