"""`hostd preview MODEL --layer N -o OUT.png`: a picture of one layer's toolpaths."""

from __future__ import annotations

import argparse

from hostd.app.cli import UsageError
from hostd.app.commands.slice import load_plan, load_settings
from slicer.output.preview import render_layer


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``hostd preview``."""
    p.add_argument("model", metavar="MODEL")
    p.add_argument("--layer", type=int, required=True, metavar="N",
                   help="layer N of the model, counted from 1 as everywhere (-1: the last)")
    p.add_argument("-o", "--output", metavar="OUT.png", required=True)
    p.add_argument("--field", action="store_true", help="draw the infill field and its level sets")
    p.add_argument("--config", metavar="FILE")
    p.add_argument("--set", metavar="KEY=VALUE", action="append", default=[])


def run(args) -> int:
    """Draw layer ``args.layer`` (from 1, as printed everywhere; -1: the last) to a PNG."""
    settings, bed = load_settings(args.config, args.set)
    plan = load_plan(args.model, settings, bed)
    layer = args.layer - 1 if args.layer > 0 else args.layer + plan.layer_count
    if not 0 <= layer < plan.layer_count:
        raise UsageError(f"--layer {args.layer}: the model has layers 1..{plan.layer_count}")
    try:
        render_layer(plan, layer, args.output, field=args.field)
    except OSError as exc:
        raise UsageError(f"cannot write {args.output}: {exc.strerror or exc}") from exc
    print(f"{args.output}: layer {layer + 1} of {plan.layer_count} "
          f"(z = {plan.layer_z(layer):.2f} mm, ;LAYER:{layer} in the G-code)")
    return 0
