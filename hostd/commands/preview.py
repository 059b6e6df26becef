"""`hostd preview MODEL --layer N -o OUT.png`: a picture of one layer's toolpaths."""

from __future__ import annotations

from hostd.cli import UsageError
from hostd.commands.slice import load_plan, load_settings
from slicer.preview import render_layer


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
