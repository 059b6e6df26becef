"""Pictures of `hostd tailor`: stress field and per-layer fields (Fig. 16), toolpaths (Fig. 17)."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import shapely
from PIL import Image, ImageDraw

from slicer.fields.draw import colour_map
from slicer.output.preview import render_layer
from slicer.plan import SlicePlan

SIDE_PX = 700  # width of each panel
TITLE_PX = 22
BACKGROUND = (255, 255, 255)


def stress_map(plan: SlicePlan, field_path: Path, layer: int) -> Image.Image:
    """The von Mises field of the analysis at the height of ``layer``, over the part."""
    with np.load(field_path) as data:
        points, values = data["points"], data["values"]
    axes = [np.unique(points[:, k]) for k in range(3)]
    lattice = values.reshape(tuple(len(a) for a in axes))
    z = plan.layer_z(layer) - 0.5 * plan.layer_height(layer) + axes[2][0]
    k = int(np.argmin(np.abs(axes[2] - z)))
    plane = lattice[:, :, k]  # (nx, ny)
    peak = float(values.max()) or 1.0
    xs, ys = axes[0], axes[1]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    xmin, ymin = plan.bounds[:2]
    outline = plan.outline(layer)
    inside = shapely.contains_xy(outline, gx - xs[0] + xmin, gy - ys[0] + ymin)
    rgb = colour_map(plane / peak)
    rgb[~inside] = 240
    image = Image.fromarray(np.ascontiguousarray(rgb.transpose(1, 0, 2)[::-1]), "RGB")
    scale = SIDE_PX / image.width
    image = image.resize((SIDE_PX, max(1, round(image.height * scale))), Image.NEAREST)
    draw = ImageDraw.Draw(image)
    draw.text((6, 4), f"von Mises stress, z = {z - axes[2][0]:.2f} mm: 0 (dark) .. "
              f"{peak:.1f} MPa (yellow)", fill=(0, 0, 0))
    return image


def _panel(plan: SlicePlan, layer: int, field: bool, title: str) -> Image.Image:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "layer.png"
        render_layer(plan, layer, path, field=field, size=SIDE_PX)
        image = Image.open(path).convert("RGB")
        image.load()
    return _titled(image, title)


def _titled(image: Image.Image, title: str) -> Image.Image:
    out = Image.new("RGB", (image.width, image.height + TITLE_PX), BACKGROUND)
    out.paste(image, (0, TITLE_PX))
    ImageDraw.Draw(out).text((6, 5), title, fill=(0, 0, 0))
    return out


def _grid(rows: list[list[Image.Image]]) -> Image.Image:
    width = max(sum(p.width for p in row) for row in rows)
    height = sum(max(p.height for p in row) for row in rows)
    sheet = Image.new("RGB", (width, height), BACKGROUND)
    y = 0
    for row in rows:
        x = 0
        for panel in row:
            sheet.paste(panel, (x, y))
            x += panel.width
        y += max(p.height for p in row)
    return sheet


def infill_layer(plan: SlicePlan) -> int:
    """A layer in the middle of the part, where the infill is (an odd one)."""
    middle = plan.layer_count // 2
    return middle if middle % 2 else max(middle - 1, 0)


def write_pictures(out: Path, plans: dict[str, SlicePlan], field_path: Path) -> None:
    """``fig16.png`` (the stress field; H_lin and H_in on an odd and an even layer) and
    ``fig17.png`` (each plan's toolpaths on one layer) in ``out``."""
    linear = plans["Linear"]
    odd = infill_layer(linear)
    even = min(odd + 1, linear.layer_count - 1)
    rows = [[_titled(stress_map(linear, field_path, odd), "stress field (built-in analysis)")]]
    for name, plan in plans.items():
        label = "H_lin" if name == "Linear" else f"H_in ({name})"
        rows.append([_panel(plan, i, True, f"{label}, layer {i}") for i in (odd, even)])
    _grid(rows).save(out / "fig16.png")
    _grid([[_panel(plan, odd, False, f"{name}: toolpaths of layer {odd}")]
           for name, plan in plans.items()]).save(out / "fig17.png")
