"""A picture of one layer: outline, walls, skin, infill and support in different colours (PNG)."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np
import shapely
from PIL import Image, ImageDraw
from PIL.PngImagePlugin import PngInfo

from slicer.paths.layer import FILL, SKIN, SUPPORT, WALL_INNER, WALL_OUTER

if TYPE_CHECKING:
    from slicer.plan import SlicePlan

COLOURS = {
    WALL_OUTER: (220, 50, 47),
    WALL_INNER: (245, 150, 40),
    SKIN: (200, 170, 0),
    FILL: (40, 160, 70),
    SUPPORT: (60, 110, 220),
}
BACKGROUND = (250, 250, 247)
OUTLINE = (215, 215, 210)
_MARGIN_MM = 3.0


def render_layer(
    plan: SlicePlan, i: int, path: str | os.PathLike[str], field: bool = False, size: int = 900
) -> None:
    """Write layer ``i`` of ``plan`` as a PNG at ``path`` (its title also as the PNG's
    ``Title`` text, :func:`layer_title`).

    The view covers the whole model's footprint (the same frame for every
    layer), ``size`` pixels on its longer side. With ``field=True`` the infill
    field is drawn underneath as a colour map with its level sets
    (``slicer.fields.draw.draw_field``, imported only then).
    """
    xmin, ymin, xmax, ymax = plan.bounds
    xmin, ymin, xmax, ymax = (
        xmin - _MARGIN_MM,
        ymin - _MARGIN_MM,
        xmax + _MARGIN_MM,
        ymax + _MARGIN_MM,
    )
    scale = size / max(xmax - xmin, ymax - ymin)
    width = max(1, round((xmax - xmin) * scale))
    height = max(1, round((ymax - ymin) * scale))
    image = Image.new("RGB", (width, height), BACKGROUND)
    draw = ImageDraw.Draw(image)

    def px(coords: np.ndarray) -> list[tuple[float, float]]:
        x = (coords[:, 0] - xmin) * scale
        y = (ymax - coords[:, 1]) * scale
        return list(zip(x.tolist(), y.tolist(), strict=True))

    outline = plan.outline(i)
    for poly in shapely.get_parts(outline):
        draw.polygon(px(shapely.get_coordinates(poly.exterior)), fill=(236, 236, 232))
        for hole in poly.interiors:
            draw.polygon(px(shapely.get_coordinates(hole)), fill=BACKGROUND)
    if field:
        from slicer.fields.draw import paint_field

        ctx = plan.layer_context(i)
        settings = plan.settings
        inset = settings.line_width * (settings.perimeters - settings.infill_overlap)
        region = shapely.buffer(ctx.domain, -inset) if inset > 0 else ctx.domain
        paint_field(image, ctx, plan.infill_field, region, (xmin, ymin, xmax, ymax), scale)
        draw = ImageDraw.Draw(image)
    for poly in shapely.get_parts(outline):
        for ring in (poly.exterior, *poly.interiors):
            draw.line(px(shapely.get_coordinates(ring)), fill=OUTLINE, width=1)
    line_px = max(1, round(plan.settings.line_width * scale * 0.8))
    for p in plan.layer_toolpaths(i):
        draw.line(px(p.coords), fill=COLOURS.get(p.kind, (0, 0, 0)), width=line_px, joint="curve")
    _legend(draw, plan, i)
    info = PngInfo()
    info.add_text("Title", layer_title(plan, i))  # the drawn title, readable as text too
    image.save(path, format="PNG", pnginfo=info)


def layer_title(plan: SlicePlan, i: int) -> str:
    """The picture's title: ``layer N of M`` with N counted from 1, and the layer's height."""
    return f"layer {i + 1} of {plan.layer_count}  z={plan.layer_z(i):.2f} mm"


def _legend(draw: ImageDraw.ImageDraw, plan: SlicePlan, i: int) -> None:
    """Layer number, height and the colour key in the top-left corner."""
    draw.text((8, 6), layer_title(plan, i), fill=(0, 0, 0))
    y = 22
    for name, colour in COLOURS.items():
        draw.rectangle((8, y + 3, 20, y + 11), fill=colour)
        draw.text((26, y), name.lower(), fill=(60, 60, 60))
        y += 14
