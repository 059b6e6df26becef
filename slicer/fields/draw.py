"""A picture of an infill field: its values as a colour map over the layer, level sets on top."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import shapely
from numpy.typing import NDArray
from PIL import Image, ImageDraw

from slicer.fields.base import InfillField, LayerContext
from slicer.fields.paths import prepared

MAX_SIDE_PX = 900
MARGIN_MM = 2.0
BAR_PX = 18
# perceptually ordered anchors (dark blue, teal, green, yellow), interpolated linearly
ANCHORS = np.array(
    [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=float
)
OUTSIDE = (236, 236, 236)
PATH_COLOUR = (0, 0, 0)
WALL_COLOUR = (220, 40, 40)


def colour_map(values: np.ndarray) -> NDArray[np.uint8]:
    """Values in [0, 1] (any shape) to RGB: (..., 3) uint8."""
    t = np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * (len(ANCHORS) - 1)
    low = np.minimum(np.floor(t).astype(int), len(ANCHORS) - 2)
    frac = (t - low)[..., None]
    mixed = ANCHORS[low] * (1.0 - frac) + ANCHORS[low + 1] * frac
    rgb: NDArray[np.uint8] = mixed.astype(np.uint8)
    return rgb


def draw_field(
    ctx: LayerContext,
    field: InfillField,
    region: shapely.Geometry,
    walls: shapely.Geometry | None,
    path: str | Path,
) -> Path:
    """Write a PNG of ``field`` over the layer domain ``ctx.domain`` to ``path``.

    The field's values are a colour map (dark blue low, yellow high, scaled to the
    1st..99th percentile on the layer), its toolpaths (level sets clipped to
    ``region`` at the spacing ``infill.density`` asks for) are drawn in black and
    ``walls`` (lines or polygons, optional) in red; a colour bar with the value
    range sits on the right. Returns the path written.
    """
    path = Path(path)
    domain = ctx.domain
    xmin, ymin, xmax, ymax = domain.bounds if not domain.is_empty else region.bounds
    frame = (xmin - MARGIN_MM, ymin - MARGIN_MM, xmax + MARGIN_MM, ymax + MARGIN_MM)
    scale = MAX_SIDE_PX / max(frame[2] - frame[0], frame[3] - frame[1], 1e-6)
    width_px = max(1, math.ceil((frame[2] - frame[0]) * scale))
    height_px = max(1, math.ceil((frame[3] - frame[1]) * scale))
    image = Image.new("RGB", (width_px, height_px), OUTSIDE)
    low, high = paint_field(image, ctx, field, region, frame, scale)
    if walls is not None and not walls.is_empty:
        lines = shapely.boundary(walls) if walls.area > 0 else walls
        _draw_lines(ImageDraw.Draw(image), lines, _mapper(frame, scale), WALL_COLOUR, 2)
    canvas = Image.new("RGB", (width_px + 4 * BAR_PX + 40, height_px), (255, 255, 255))
    canvas.paste(image, (0, 0))
    _colour_bar(canvas, width_px + BAR_PX, height_px, low, high)
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.save(path, format="PNG")
    return path


def paint_field(
    image: Image.Image,
    ctx: LayerContext,
    field: InfillField,
    region: shapely.Geometry,
    frame: tuple[float, float, float, float],
    scale: float,
) -> tuple[float, float]:
    """Paint ``field`` onto an existing RGB ``image`` whose pixels show ``frame``
    (xmin, ymin, xmax, ymax) mm at ``scale`` px/mm, y up: the colour map inside
    ``ctx.domain`` and the level sets clipped to ``region`` in black.

    For callers that compose their own picture (the layer preview). Returns the
    (low, high) field values mapped to the ends of the colour map.
    """
    xmin, _, _, ymax = frame
    width_px, height_px = image.size
    cols, rows = np.meshgrid(np.arange(width_px) + 0.5, np.arange(height_px) + 0.5)
    xs = xmin + cols / scale
    ys = ymax - rows / scale
    domain = ctx.domain
    inside = shapely.contains_xy(prepared(domain), xs.ravel(), ys.ravel()).reshape(xs.shape)
    rgb = np.asarray(image.convert("RGB")).copy()
    low = high = 0.0
    if inside.any():
        values = np.asarray(field.sample(xs[inside], ys[inside], ctx), dtype=float)
        finite = values[np.isfinite(values)]
        if finite.size:
            low, high = (float(v) for v in np.percentile(finite, [1.0, 99.0]))
            span = high - low if high > low else 1.0
            rgb[inside] = colour_map((values - low) / span)
    image.paste(Image.fromarray(rgb, "RGB"), (0, 0))
    density = ctx.settings.infill_density
    if density > 0 and not region.is_empty:
        lines = field.paths(region, ctx, ctx.settings.line_width / density)
        _draw_lines(ImageDraw.Draw(image), lines, _mapper(frame, scale), PATH_COLOUR, 2)
    return low, high


def _mapper(
    frame: tuple[float, float, float, float], scale: float
) -> Callable[[np.ndarray], list[tuple[float, float]]]:
    """Coordinates (n, 2) mm to pixel positions in a picture of ``frame`` at ``scale``."""
    xmin, _, _, ymax = frame

    def to_px(coords: np.ndarray) -> list[tuple[float, float]]:
        x = (coords[:, 0] - xmin) * scale
        y = (ymax - coords[:, 1]) * scale
        return list(zip(x.tolist(), y.tolist(), strict=True))

    return to_px


def _draw_lines(
    pen: ImageDraw.ImageDraw,
    geom: shapely.Geometry,
    to_px: Callable[[np.ndarray], list[tuple[float, float]]],
    colour: tuple[int, int, int],
    width: int,
) -> None:
    """Draw every line part of ``geom`` (coordinates mapped by ``to_px``)."""
    for part in shapely.get_parts(shapely.get_parts(geom)):
        if shapely.get_type_id(part) in (1, 2) and len(part.coords) >= 2:
            pen.line(to_px(np.asarray(part.coords)), fill=colour, width=width)


def _colour_bar(canvas: Image.Image, left: int, height: int, low: float, high: float) -> None:
    """A vertical colour bar, high at the top, labelled with the value range."""
    top, bottom = 20, max(21, height - 20)
    ramp = np.linspace(1.0, 0.0, bottom - top)[:, None].repeat(BAR_PX, axis=1)
    canvas.paste(Image.fromarray(colour_map(ramp), "RGB"), (left, top))
    pen = ImageDraw.Draw(canvas)
    pen.text((left, 2), f"{high:.3g}", fill=(0, 0, 0))
    pen.text((left, bottom + 4), f"{low:.3g}", fill=(0, 0, 0))
