"""How right the ETA is: the refitted ETA, the slicer's plain estimate and the mean layer time,
against the time each print really had left, on the simulated Marlin's virtual clock.

Each model is sliced with the benchmark settings; its G-code (start block, layers, end
block) is fed to the simulated Marlin's planner (``drivers.sim.feed``: 16 blocks, Marlin's
acceleration and junction deviation, arcs cut as ``plan_arc`` cuts them) on a virtual
clock, which gives the moment each line is acknowledged and the moment the print ends.
The daemon's ETA (:class:`hostd.printing.eta.EtaModel`) is then replayed on those moments as the
runner drives it: printing starts when the start block is acknowledged, a layer is done
when its last line is, and only the layers the daemon would have sliced by then
(``--lookahead`` past the one being sent) have the slicer's estimate; the others are
guessed from the model's geometry. Nothing depends on the machine's load.

The slicing settings are the benchmark's with the acceleration the daemon would learn
from the printer: the simulated Marlin's ``M503`` answer (``--printer-acceleration``,
3000 mm/s² as Marlin's default) read as the link reads it, unless ``--set
acceleration=...`` chooses one, as ``[slicing]`` would.

    .venv/bin/python bench/eta.py [--plot docs/eta_error.png] [--set KEY=VALUE ...]
        [--printer-acceleration A] [MODEL ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.slice_vs_peers import OUR_SETTINGS
from drivers.link.motion import parse_motion_report
from drivers.link.protocol import strip_comment
from drivers.sim.config import SimulatorConfig
from drivers.sim.feed import simulate_feed
from drivers.sim.planner import PlannerSettings
from drivers.sim.report import report_lines
from hostd.config import config_from_mapping
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.eta import EtaModel
from hostd.printing.printermotion import with_printer_motion
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings, parse_assignment

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("cube20_xyz.stl", "dogbone_100x30x5.stl", "candle_stand.stl", "rocker_arm.stl",
          "bunny.stl")
COLOURS = {"refit": (200, 40, 40), "slicer": (40, 90, 200), "mean layer": (60, 150, 60)}
BED = (200.0, 200.0, 200.0)
LAST_MINUTE = 60.0  # s: below this the errors are given in seconds


def model_path(name: str) -> Path:
    shared = ROOT.parent / "shared" / "models" / name
    return shared if shared.exists() else ROOT / "tests" / "data" / name


def printed(plan: SlicePlan, printer: PlannerSettings) -> tuple[list, float, np.ndarray, float]:
    """Slice every layer and print the job on the virtual clock: (each layer's LayerCode,
    when the start block was acknowledged, (layers,) when each layer's last line was,
    when the print ended), seconds."""
    codes = [plan.layer_code(i) for i in range(plan.layer_count)]
    lines = [c for c in plan.start_gcode() if strip_comment(c)]
    started = len(lines)
    ends = []
    for code in codes:
        lines += [c for c in code.lines if strip_comment(c)]
        ends.append(len(lines))
    lines += [c for c in plan.end_gcode() if strip_comment(c)]
    acks: list[float] = []
    result = simulate_feed(lines, 0, acks=acks, settings=printer)
    ack = np.array(acks)
    start = float(ack[started - 1]) if started else 0.0
    return codes, start, ack[np.array(ends) - 1], result.print_s


def replay(plan: SlicePlan, settings: SliceSettings, lookahead: int,
           printer: PlannerSettings) -> dict[str, np.ndarray]:
    """The ETAs at each layer's completion, and the truth; see the module docstring."""
    codes, start, done, end = printed(plan, printer)
    n = plan.layer_count
    schedule = LayerSchedule(plan, settings)
    eta = EtaModel(schedule, n, 0)
    eta.start(start)
    eta.wait_measured()
    plain = np.array([c.time_s for c in codes])
    refit = np.full(n, np.nan)
    sliced = -1
    for i in range(n):
        while sliced < min(n - 1, i + 1 + lookahead):
            sliced += 1
            # what schedule.layer_gcode records when the daemon slices the layer
            code = codes[sliced]
            schedule.estimates[sliced] = (code.time_s, code.filament_mm)
            schedule.lines[sliced] = sum(1 for c in code.lines if strip_comment(c))
        eta.layer_done(i, float(done[i]))
        value = eta.remaining(float(done[i]))
        refit[i] = np.nan if value is None else value
    actual = end - done
    layers = np.arange(n)
    mean = (done - start) / (layers + 1) * (n - 1 - layers)
    left = np.concatenate([np.cumsum(plain[::-1])[::-1][1:], [0.0]])
    return {
        "progress": (layers + 1) / n,
        "actual": actual,
        "print_s": np.array([end - start]),
        "plain_s": np.array([plain.sum()]),
        "refit": (refit - actual) / actual,
        "slicer": (left - actual) / actual,
        "mean layer": (mean - actual) / actual,
    }


def plot(results: dict[str, dict[str, np.ndarray]], path: Path, limit: float = 30.0) -> None:
    """One panel per model: error (%) against progress, each estimate in its colour."""
    from PIL import Image, ImageDraw

    width, panel, margin = 900, 220, 50
    image = Image.new("RGB", (width, panel * len(results) + 30), "white")
    draw = ImageDraw.Draw(image)
    for row, (name, data) in enumerate(results.items()):
        top = 30 + row * panel
        x0, x1, y0, y1 = margin, width - 20, top + 20, top + panel - 30

        def at(progress, error, x0=x0, x1=x1, y0=y0, y1=y1):
            x = x0 + (x1 - x0) * progress
            y = (y0 + y1) / 2 - (y1 - y0) / 2 * np.clip(error * 100, -limit, limit) / limit
            return x, y

        draw.rectangle((x0, y0, x1, y1), outline=(150, 150, 150))
        for level in (-limit, -3, 0, 3, limit):
            _, y = at(0, level / 100)
            draw.line((x0, y, x1, y), fill=(220, 220, 220) if level else (120, 120, 120))
            draw.text((5, y - 6), f"{level:+.0f}%", fill=(0, 0, 0))
        draw.line((at(0.1, 0)[0], y0, at(0.1, 0)[0], y1), fill=(200, 200, 200))
        draw.text((x0 + 5, top + 3), f"{name}: ETA error vs progress (clipped at "
                  f"{limit:.0f} %; grey lines at +-3 % and 10 % progress)", fill=(0, 0, 0))
        for key, colour in COLOURS.items():
            ok = ~np.isnan(data[key])
            points = [at(p, e) for p, e in zip(data["progress"][ok], data[key][ok], strict=True)]
            if len(points) > 1:
                draw.line(points, fill=colour, width=2)
    for k, (key, colour) in enumerate(COLOURS.items()):
        draw.text((margin + 160 * k, 8), key, fill=colour)
    image.save(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plot", type=Path, help="write the errors as a PNG")
    parser.add_argument("--limit", type=float, default=30.0, help="the plot's error scale, %%")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a slicing setting on top of the benchmark's (repeatable)")
    parser.add_argument("--lookahead", type=int, default=4, help="layers sliced ahead")
    parser.add_argument("--printer-acceleration", type=float, default=3000.0,
                        help="the simulated printer's acceleration, mm/s² (its M503)")
    parser.add_argument("models", nargs="*", default=list(MODELS))
    args = parser.parse_args()
    mapping = dict(parse_assignment(kv) for kv in (*OUR_SETTINGS, *args.set))
    printer = SimulatorConfig(acceleration=args.printer_acceleration).planner()
    motion = parse_motion_report(report_lines(printer))  # what the daemon reads at connect
    config = config_from_mapping({"slicing": mapping}, ROOT)
    settings = with_printer_motion(config, mapping, SliceSettings.from_mapping(mapping), motion)
    results = {}
    print(f"settings: benchmark's + {args.set or 'nothing'}; lookahead {args.lookahead}; "
          f"printer acceleration {args.printer_acceleration:g} mm/s², slicer's "
          f"{settings.acceleration:g} mm/s²")
    print(f"{'model':20} {'layers':>6} {'print s':>8} {'slicer s':>8} {'run s':>6}   "
          "max |error| from 10 % on while a minute or more is left: refit / slicer / "
          "mean layer; the refit's largest error in the last minute")
    for name in args.models:
        began = time.monotonic()
        plan = SlicePlan.from_file(model_path(name), settings, BED)
        data = replay(plan, settings, args.lookahead, printer)
        results[name] = data
        tail = (data["progress"] >= 0.1) & (data["actual"] >= LAST_MINUTE)
        cells = [f"{np.nanmax(np.abs(data[key][tail])) * 100:5.1f} %" for key in COLOURS]
        end = data["actual"] < LAST_MINUTE
        off = np.nanmax(np.abs(data["refit"][end] * data["actual"][end])) if end.any() else 0.0
        cells[-1] += f"   {off:5.1f} s"
        print(f"{name:20} {len(data['actual']):6d} {data['print_s'][0]:8.0f} "
              f"{data['plain_s'][0]:8.0f} {time.monotonic() - began:6.1f}   "
              + " / ".join(cells))
    if args.plot:
        plot(results, args.plot, args.limit)
        print(f"plot written to {args.plot}")


if __name__ == "__main__":
    main()
