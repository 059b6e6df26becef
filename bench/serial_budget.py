"""Serial budget: does the G-code keep a Marlin planner fed over the wire? Lines, underruns.

For each model, infill field and print speed it slices (a) ours with arcs and the
line budget of the wire (``gcode.arcs=on``, ``gcode.baud`` = the wire's baud) and
(b) ours without arcs, and takes (c) PrusaSlicer's G-code of the same model at
the same speed. Each is fed to the simulated Marlin (``drivers.sim.feed``, a
16-block planner with Marlin's defaults, on a virtual clock) over a wire of
115200 and 250000 baud by our link (send-ahead window of 4 lines and 127
bytes); PrusaSlicer's also by (d) a send-and-wait host. Per run: G-code lines
and bytes, underruns (planner empty), stalls (a block that must brake to a stop
because nothing is queued behind it), starved seconds, the print's time and the
time lost against the same G-code on an endless wire. And the outer-wall IoU of
(a) against (b).

Usage (from the repository root):
    .venv/bin/python bench/serial_budget.py            # bunny; linear, wave; 100, 150 mm/s
    .venv/bin/python bench/serial_budget.py --full     # every shared model, field and speed
    .venv/bin/python bench/serial_budget.py --models candle_stand --fields wave --speeds 60
    .venv/bin/python bench/serial_budget.py --targets --models cube20_xyz   # the underrun targets
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import gcodeparse
from bench.peers import prusaslicer
from drivers.sim.feed import simulate_feed
from slicer.output.gcodefile import iter_layer_texts
from slicer.plan import SlicePlan
from slicer.settings import INFILL_FIELDS, SliceSettings

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "models"
OUT = ROOT / "bench" / "out"
BAUDS = (115200, 250000)
SPEEDS = (60.0, 100.0, 150.0)
# the no-underrun conditions: (mm/s, baud)
TARGETS = ((100.0, 115200), (150.0, 250000))
DEFAULT = {"models": ("bunny",), "fields": ("linear", "wave"), "speeds": (100.0, 150.0)}
SKIP_MODELS = ("bad_triangle_soup",)
# our settings equal to the peers' (see bench/peers.py)
OURS = {
    "layer_height": 0.2, "first_layer_height": 0.2, "line_width": 0.4, "perimeters": 2,
    "top_layers": 3, "bottom_layers": 3, "infill.density": 0.2, "filament_diameter": 1.75,
}
EXPRESSION = "sin(x / 4) * 3 + y + 0.3 * d"
_PRUSA_SPEEDS = ("--perimeter-speed", "--external-perimeter-speed", "--small-perimeter-speed",
                 "--infill-speed", "--solid-infill-speed", "--top-solid-infill-speed",
                 "--gap-fill-speed")


@dataclass
class Row:
    """One G-code fed over one wire."""

    model: str
    field: str
    speed: float
    baud: int
    variant: str  # a: ours with arcs, b: ours without, c: PrusaSlicer, d: PrusaSlicer sent-and-wait
    lines: int
    bytes: int
    underruns: int
    stalls: int
    starved_s: float
    print_s: float
    lost_s: float  # print_s less the same G-code's time on an endless wire (--lost; else nan)


def _field_settings(field: str, workdir: Path) -> dict[str, object]:
    values: dict[str, object] = {"infill.field": field}
    if field == "expression":
        values["infill.expression"] = EXPRESSION
    if field == "stress":
        # a smooth made-up stress over the bed, in the model's frame (x, y, value)
        path = workdir / "stress.csv"
        if not path.exists():
            import numpy as np

            g = np.arange(-150.0, 151.0, 10.0)
            x, y = np.meshgrid(g, g)
            v = 1.5 + np.sin(x / 25.0) * np.cos(y / 25.0)
            np.savetxt(path, np.column_stack([x.ravel(), y.ravel(), v.ravel()]), delimiter=",")
        values["infill.file"] = str(path)
    return values


def _slice(geometry: SlicePlan, values: dict[str, object], jobs: int = 1) -> list[str]:
    """The whole program's lines; ``jobs`` > 1 slices layers in forked workers (same bytes)."""
    plan = geometry.with_settings(SliceSettings.from_mapping(values, base=geometry.settings))
    lines = plan.start_gcode()
    if jobs > 1:
        for text, _, _ in iter_layer_texts(plan, jobs):
            lines += text.splitlines()
    else:
        for i in range(plan.layer_count):
            lines += plan.layer_gcode(i)
    return lines + plan.end_gcode()


def _prusa(model: Path, speed: float, workdir: Path) -> list[str] | None:
    peer = prusaslicer()
    if peer is None:
        return None
    out = workdir / f"{model.stem}_{speed:g}_prusa.gcode"
    if not out.exists():
        command = peer.command(model, out)
        for opt in _PRUSA_SPEEDS:
            command[1:1] = [opt, f"{speed:g}"]
        import subprocess

        done = subprocess.run(command, capture_output=True, text=True, timeout=900, check=False)
        if done.returncode != 0:
            print(f"  PrusaSlicer failed on {model.name}: {done.stderr.strip()[-200:]}")
            return None
    return out.read_text().splitlines()


def _feed_rows(
    lines: list[str], key: tuple[str, str, float], variant: str, bauds: tuple[int, ...],
    send_and_wait: bool = False, lost: bool = False,
) -> list[Row]:
    ideal = simulate_feed(lines, 0).print_s if lost else float("nan")
    rows = []
    for baud in bauds:
        r = simulate_feed(lines, baud, send_and_wait=send_and_wait)
        rows.append(Row(*key, baud, variant, r.lines, r.bytes, r.underruns, r.stalls,
                        round(r.starved_s, 3), round(r.print_s, 1), round(r.print_s - ideal, 1)))
        print(f"  {key[0]:>13} {key[1]:>10} {key[2]:5g} {baud:6d} {variant}"
              f" {r.lines:8d} lines {r.bytes / 1e6:6.2f} MB  underruns {r.underruns:5d}"
              f"  stalls {r.stalls:6d}  print {r.print_s:8.1f} s  lost {r.print_s - ideal:7.1f} s",
              flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--full", action="store_true", help="every model, field and speed")
    parser.add_argument("--models", default="", help="comma-separated model stems")
    parser.add_argument("--fields", default="", help="comma-separated infill fields")
    parser.add_argument("--speeds", default="", help="comma-separated speeds, mm/s")
    parser.add_argument("--no-peer", action="store_true", help="leave PrusaSlicer out")
    parser.add_argument("--lost", action="store_true",
                        help="also feed each G-code over an endless wire, for the time lost")
    parser.add_argument("--resolution", type=float, default=None,
                        help="our resolution, mm (default: the setting's default)")
    parser.add_argument("--lines-only", action="store_true",
                        help="count lines against PrusaSlicer's only (no feed simulation)")
    parser.add_argument("--targets", action="store_true",
                        help="ours with arcs fed at 100 mm/s over 115200 baud and 150 mm/s over "
                             "250000 only (the no-underrun targets), with the outer-wall IoU")
    parser.add_argument("--jobs", type=int, default=1,
                        help="forked processes slicing layers (--targets, --lines-only; same "
                             "G-code)")
    parser.add_argument("--iou", action="store_true",
                        help="with --lines-only: also slice ours without arcs, for the "
                             "outer-wall IoU")
    parser.add_argument("--out", type=Path, default=OUT / "serial_budget.json")
    args = parser.parse_args(argv)
    every = sorted(p.stem for p in MODELS.glob("*.stl") if p.stem not in SKIP_MODELS)
    models = (args.models.split(",") if args.models
              else every if args.full else list(DEFAULT["models"]))
    fields = (args.fields.split(",") if args.fields
              else list(INFILL_FIELDS) if args.full else list(DEFAULT["fields"]))
    speeds = ([float(s) for s in args.speeds.split(",")] if args.speeds
              else list(SPEEDS) if args.full else list(DEFAULT["speeds"]))
    if args.lines_only:
        return _lines_only(models, fields, speeds, args.out, args.jobs, args.iou)
    if args.targets:
        pairs = [t for t in TARGETS if not args.speeds or t[0] in speeds]
        return _targets(models, fields, pairs, args.out, args.jobs)
    rows: list[Row] = []
    ious: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(prefix="serial-budget-") as tmp:
        work = Path(tmp)
        for stem in models:
            model = MODELS / f"{stem}.stl"
            ours = {**OURS, **({} if args.resolution is None else {"resolution": args.resolution})}
            geometry = SlicePlan.from_file(model, SliceSettings.from_mapping(ours),
                                           bed=(200.0, 200.0, 200.0))
            for speed in speeds:
                if not args.no_peer:
                    prusa = _prusa(model, speed, work)
                    if prusa is not None:
                        rows += _feed_rows(prusa, (stem, "prusa", speed), "c", BAUDS,
                                           lost=args.lost)
                        rows += _feed_rows(prusa, (stem, "prusa", speed), "d", BAUDS, True,
                                           lost=args.lost)
                for field in fields:
                    base = {**_field_settings(field, work), "print_speed": speed,
                            "wall_speed": speed}
                    key = (stem, field, speed)
                    plain = _slice(geometry, {**base, "gcode.arcs": "off"})
                    rows += _feed_rows(plain, key, "b", BAUDS, lost=args.lost)
                    plain_moves = gcodeparse.parse_moves(plain)
                    for baud in BAUDS:
                        arcs = _slice(geometry, {**base, "gcode.arcs": "on", "gcode.baud": baud})
                        rows += _feed_rows(arcs, key, "a", (baud,), lost=args.lost)
                        agreement = gcodeparse.wall_agreement(
                            gcodeparse.parse_moves(arcs), plain_moves, align=False)
                        ious.append({"model": stem, "field": field, "speed": speed, "baud": baud,
                                     "outer_wall_iou": round(agreement.mean_iou, 5)})
                        print(f"  outer-wall IoU (a) against (b): {agreement.mean_iou:.5f}")
    _summary(rows, ious)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"rows": [asdict(r) for r in rows], "iou": ious}, indent=1))
    print(f"written {args.out}")
    return 0


def _commands(lines: list[str]) -> int:
    """Lines a host sends: neither empty nor comments only."""
    return sum(1 for line in lines if line.split(";", 1)[0].strip())


def _lines_only(
    models: list[str], fields: list[str], speeds: list[float], out: Path, jobs: int = 1,
    iou: bool = False,
) -> int:
    """Our line count with arcs and the 250000-baud budget against PrusaSlicer's, for every
    model, field and speed given; the table and the runs over PrusaSlicer's count. With
    ``iou``, the outer-wall IoU against ours without arcs too."""
    table: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(prefix="serial-budget-") as tmp:
        work = Path(tmp)
        for stem in models:
            model = MODELS / f"{stem}.stl"
            geometry = SlicePlan.from_file(model, SliceSettings.from_mapping(OURS),
                                           bed=(200.0, 200.0, 200.0))
            for speed in speeds:
                prusa = _prusa(model, speed, work)
                peer = _commands(prusa) if prusa is not None else None
                for field in fields:
                    base = {**_field_settings(field, work), "print_speed": speed,
                            "wall_speed": speed, "gcode.arcs": "on", "gcode.baud": 250000}
                    arcs = _slice(geometry, base, jobs)
                    ours = _commands(arcs)
                    row: dict[str, object] = {"model": stem, "field": field, "speed": speed,
                                              "ours": ours, "prusaslicer": peer}
                    ratio = f"{ours / peer:.3f}" if peer else "-"
                    if iou:
                        plain = _slice(geometry, {**base, "gcode.arcs": "off", "gcode.baud": 0},
                                       jobs)
                        row["plain"] = _commands(plain)
                        row["outer_wall_iou"] = round(gcodeparse.wall_agreement(
                            gcodeparse.parse_moves(arcs), gcodeparse.parse_moves(plain),
                            align=False).mean_iou, 5)
                        ratio += f"  no arcs {row['plain']}  outer-wall IoU {row['outer_wall_iou']}"
                    table.append(row)
                    print(f"  {stem:>16} {field:>10} {speed:5g}  ours {ours:8d}  "
                          f"PrusaSlicer {peer if peer is not None else '-':>8}  ratio {ratio}",
                          flush=True)
    over = [r for r in table if r["prusaslicer"] and int(r["ours"]) > int(r["prusaslicer"])]
    print(f"\nwith arcs, line count above PrusaSlicer's: {len(over)} of {len(table)} runs")
    for r in over:
        print(f"  {r['model']} {r['field']} {r['speed']:g} mm/s: {r['ours']} > {r['prusaslicer']}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"lines": table}, indent=1))
    print(f"written {out}")
    return 0


def _targets(
    models: list[str], fields: list[str], pairs: list[tuple[float, int]], out: Path,
    jobs: int = 1,
) -> int:
    """Ours with arcs and the wire's budget fed at each (speed, baud) of ``pairs`` alone:
    lines, underruns, stalls, and the outer-wall IoU against ours without arcs.

    Ours without arcs (no wire, so no budget) differs between speeds in feedrates
    only, so it is sliced once per model and field, at the first pair's speed, and
    each pair's IoU is taken against it. The rows are written after every model
    and field, so a run stopped early keeps what it took.
    """
    rows: list[Row] = []
    ious: list[dict[str, object]] = []
    with tempfile.TemporaryDirectory(prefix="serial-budget-") as tmp:
        work = Path(tmp)
        for stem in models:
            geometry = SlicePlan.from_file(MODELS / f"{stem}.stl", SliceSettings.from_mapping(OURS),
                                           bed=(200.0, 200.0, 200.0))
            for field in fields:
                plain_moves = None
                for speed, baud in pairs:
                    base = {**_field_settings(field, work), "print_speed": speed,
                            "wall_speed": speed}
                    if plain_moves is None:
                        plain_moves = gcodeparse.parse_moves(
                            _slice(geometry, {**base, "gcode.arcs": "off"}, jobs))
                    arcs = _slice(geometry, {**base, "gcode.arcs": "on", "gcode.baud": baud}, jobs)
                    rows += _feed_rows(arcs, (stem, field, speed), "a", (baud,))
                    agreement = gcodeparse.wall_agreement(
                        gcodeparse.parse_moves(arcs), plain_moves, align=False)
                    ious.append({"model": stem, "field": field, "speed": speed, "baud": baud,
                                 "outer_wall_iou": round(agreement.mean_iou, 5)})
                    print(f"  outer-wall IoU (a) against (b): {agreement.mean_iou:.5f}", flush=True)
                out.parent.mkdir(parents=True, exist_ok=True)
                out.write_text(json.dumps({"rows": [asdict(r) for r in rows], "iou": ious},
                                          indent=1))
    _summary(rows, ious)
    print(f"written {out}")
    return 0


def _summary(rows: list[Row], ious: list[dict[str, object]]) -> None:
    """The targets: lines against PrusaSlicer's, underruns where none are allowed, IoU."""
    prusa = {(r.model, r.speed): r.lines for r in rows if r.variant == "c"}
    ours = [r for r in rows if r.variant == "a"]
    over = [r for r in ours if (r.model, r.speed) in prusa and r.lines > prusa[r.model, r.speed]]
    print(f"\nwith arcs, line count above PrusaSlicer's: {len(over)} of {len(ours)} runs")
    for r in over:
        print(f"  {r.model} {r.field} {r.speed:g} mm/s: {r.lines} > {prusa[r.model, r.speed]}")
    strict = [r for r in ours if (r.baud, r.speed) in ((250000, 150.0), (115200, 100.0))]
    bad = [r for r in strict if r.underruns]
    print(f"underruns at 250000/150 and 115200/100 (ours with arcs): {len(bad)} of "
          f"{len(strict)} runs with any; stalls there: {sum(r.stalls for r in strict)}")
    if ious:
        print(f"outer-wall IoU with arcs against without: min "
              f"{min(float(i['outer_wall_iou']) for i in ious):.5f}")


if __name__ == "__main__":
    raise SystemExit(main())
