"""Filament per feature type (`;TYPE:`), `hostd slice` against PrusaSlicer, on chosen models.

Slices each model with both at the settings of `bench/slice_vs_peers.py` (PrusaSlicer's
G-code is kept in `bench/out/by_type/` and reused) and prints, per slicer and feature
type, the filament fed (mm), the length laid (mm) and filament per mm laid, then the
whole model's filament against PrusaSlicer's and against the model's volume (the
filament that fills each layer's outline area exactly). Shows which feature makes a
model's filament differ from PrusaSlicer's.

Usage (from the repository root):
    .venv/bin/python bench/filament_by_type.py tall_tower vase_twisted
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import gcodeparse
from bench.layer_cpu import SETTINGS, model_path
from bench.peers import prusaslicer
from bench.slice_vs_peers import BED_TOML, OUT, ours_command

FOLDER = OUT / "by_type"


def by_type(path: Path) -> tuple[dict[str, tuple[float, float]], float]:
    """(type -> (filament mm, length laid mm), total filament mm) of a G-code file."""
    moves = gcodeparse.read_moves(path)
    laid = moves.extruding
    out = {}
    for i, name in enumerate(moves.types):
        mask = laid & (moves.type_id == i)
        if mask.any():
            out[name] = (float(moves.de[mask].sum()), float(moves.xy_length[mask].sum()))
    return out, float(moves.de[laid].sum())


def volume_filament(model: Path) -> float:
    """Filament (mm) that fills every layer's outline area exactly at the benchmark settings."""
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    settings = SliceSettings.from_mapping(SETTINGS)
    plan = SlicePlan.from_file(model, settings, bed=(200.0, 200.0, 200.0))
    volume = sum(
        plan.outline(i).area * plan.layer_height(i) for i in range(plan.layer_count)
    )
    return volume / settings.filament_area


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+", help="corpus or shared model names")
    args = p.parse_args(argv)
    peer = prusaslicer()
    if peer is None:
        raise SystemExit("PrusaSlicer is not available")
    FOLDER.mkdir(parents=True, exist_ok=True)
    config = FOLDER / "bed.toml"
    config.write_text(BED_TOML)
    for name in args.models:
        model = model_path(name)
        theirs, ours = FOLDER / f"{name}.prusaslicer.gcode", FOLDER / f"{name}.hostd.gcode"
        if not theirs.exists():
            peer.slice(model, theirs, timeout=600.0)
        subprocess.run(ours_command(model, ours, config), check=True)
        print(f"## {name}")
        print("| slicer | type | filament mm | laid mm | filament / laid |")
        print("|---|---|---|---|---|")
        totals = {}
        for who, path in (("PrusaSlicer", theirs), ("hostd", ours)):
            types, totals[who] = by_type(path)
            for kind, (e, length) in sorted(types.items()):
                print(f"| {who} | {kind} | {e:.1f} | {length:.1f} | {e / length:.5f} |")
        fill = volume_filament(model)
        print(f"\nhostd {totals['hostd']:.1f} mm = {totals['hostd'] / totals['PrusaSlicer']:.3f}"
              f" x PrusaSlicer's {totals['PrusaSlicer']:.1f} mm; the outlines' volume takes"
              f" {fill:.1f} mm (hostd {totals['hostd'] / fill:.3f}, PrusaSlicer"
              f" {totals['PrusaSlicer'] / fill:.3f})\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
