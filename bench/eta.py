"""How right the ETA is: the daemon's refitted ETA, the slicer's plain estimate and the mean
layer time, against the time each print really had left, on the simulated printer.

Each model is printed by a real `hostd run` on the simulated printer, sped up so that the
print takes about ``--seconds`` of wall time. At every layer completion the refitted ETA is
read from the status; the plain estimate (the slicer's seconds for the layers left, times
the time scale) and the mean layer time x layers left are computed for the same moment.
Prints a table and writes a PNG of the errors (``--plot``).

    .venv/bin/python bench/eta.py [--seconds 60] [--plot docs/eta_error.png]
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.daemonproc import Daemon, DaemonSetup
from bench.slice_vs_peers import OUR_SETTINGS
from hostd.api import ControlClient
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings, parse_assignment

ROOT = Path(__file__).resolve().parents[1]
MODELS = ("cube20_xyz.stl", "candle_stand.stl", "bunny.stl")
COLOURS = {"refit": (200, 40, 40), "slicer": (40, 90, 200), "mean layer": (60, 150, 60)}


def model_path(name: str) -> Path:
    shared = ROOT.parent / "shared" / "models" / name
    return shared if shared.exists() else ROOT / "tests" / "data" / name


def plain_estimates(model: Path) -> np.ndarray:
    """The slicer's seconds for each layer, (layers,), with the benchmark settings."""
    settings = SliceSettings.from_mapping(dict(parse_assignment(kv) for kv in OUR_SETTINGS))
    plan = SlicePlan.from_file(model, settings, (200.0, 200.0, 200.0))
    return np.array([plan.layer_code(i).time_s for i in range(plan.layer_count)])


async def watch(socket: str, daemon: Daemon, model: Path) -> tuple[list, float]:
    """(monotonic time, last completed layer, refitted ETA) at each layer; the end time."""
    samples: list[tuple[float, int, float | None]] = []
    latest = None
    async with ControlClient(socket) as client:
        daemon.drop(model)
        async for item in client.subscribe():
            if "status" in item:
                latest = item["status"]
                continue
            event = item["event"]
            if event["event"] == "layer" and latest is not None and latest.job is not None:
                samples.append((time.monotonic(), int(event["layer"]), latest.job.eta_s))
            elif event["event"] in ("done", "failed", "cancelled"):
                if event["event"] != "done":
                    raise RuntimeError(f"{model.name}: {event}")
                return samples, time.monotonic()
    raise RuntimeError("the daemon closed the connection")


def errors(samples: list, end: float, plain: np.ndarray, scale: float) -> dict[str, np.ndarray]:
    """Progress (0..1) and the relative error of each estimate at each sample."""
    times = np.array([s[0] for s in samples])
    layers = np.array([s[1] for s in samples])
    refit = np.array([np.nan if s[2] is None else s[2] for s in samples])
    actual = end - times
    n = len(plain)
    left = np.array([plain[layer + 1:].sum() for layer in layers]) * scale
    mean = (times - times[0]) / np.maximum(layers - layers[0], 1) * (n - 1 - layers)
    mean[0] = np.nan
    return {
        "progress": (layers + 1) / n,
        "actual": actual,
        "refit": (refit - actual) / actual,
        "slicer": (left - actual) / actual,
        "mean layer": (mean - actual) / actual,
    }


def plot(results: dict[str, dict[str, np.ndarray]], path: Path) -> None:
    """One panel per model: error (%) against progress, each estimate in its colour."""
    from PIL import Image, ImageDraw

    width, panel, margin = 900, 260, 50
    image = Image.new("RGB", (width, panel * len(results) + 30), "white")
    draw = ImageDraw.Draw(image)
    limit = 30.0
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
        draw.text((x0 + 5, top + 3), f"{name}: ETA error vs progress (clipped at 30 %)",
                  fill=(0, 0, 0))
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
    parser.add_argument("--seconds", type=float, default=60.0, help="wall time of each print")
    parser.add_argument("--plot", type=Path, help="write the errors as a PNG")
    parser.add_argument("models", nargs="*", default=list(MODELS))
    args = parser.parse_args()
    results = {}
    print(f"{'model':18} {'layers':>6} {'scale':>7} {'wall s':>7}   max |error| from 10 % "
          f"to 90 % (and to the end): refit / slicer / mean layer")
    for name in args.models:
        model = model_path(name)
        plain = plain_estimates(model)
        scale = args.seconds / plain.sum()
        setup = DaemonSetup(time_scale=scale, baud=0, settle_s=0.2)
        with Daemon(setup) as daemon:
            daemon.wait_ready()
            socket = next(str(p) for p in daemon.state.rglob("*.sock"))
            started = time.monotonic()
            samples, end = asyncio.run(watch(socket, daemon, model))
            wall = time.monotonic() - started
        data = errors(samples, end, plain, scale)
        results[name] = data
        window = (data["progress"] >= 0.1) & (data["progress"] <= 0.9)
        tail = data["progress"] >= 0.1
        cells = []
        for key in COLOURS:
            middle = np.nanmax(np.abs(data[key][window])) * 100
            late = np.nanmax(np.abs(data[key][tail])) * 100
            cells.append(f"{middle:5.1f} % ({late:5.1f} %)")
        print(f"{name:18} {len(plain):6d} {scale:7.4f} {wall:7.1f}   " + " / ".join(cells))
    if args.plot:
        plot(results, args.plot)
        print(f"plot written to {args.plot}")


if __name__ == "__main__":
    main()
