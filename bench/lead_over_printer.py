"""Lead over the printer: does just-in-time slicing keep layers ready ahead of the streamer?

A `hostd run` prints each model on the simulated printer at a given speed (time scale
1 = real time; 0.05 = twenty times faster, a harder test), heating skipped. The
daemon's status snapshots are read from its control socket for a bounded window and
``job.layers_ready_ahead`` is recorded for a bounded window once the job prints; the
target is >= 1 at every sample (the last layer, with nothing left to slice, excepted).

Usage (from the repository root):
    .venv/bin/python bench/lead_over_printer.py [--models dragon_100k] [--time-scales 1,0.05]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.daemonproc import Daemon, DaemonSetup
from bench.slice_vs_peers import MODELS, OUT, model_paths, stl_faces
from hostd.api import ControlClient, ControlError, Snapshot


@dataclass
class Lead:
    """Layers ready ahead during one print window."""

    model: str
    faces: int
    time_scale: float
    samples: int = 0
    starved_samples: int = 0  # samples with fewer than one layer ready ahead
    starved_layers: list[int] = field(default_factory=list)  # the layers printing then
    min_ready: int | None = None
    mean_ready: float | None = None
    layers_printed: int = 0
    layers: int = 0
    note: str = ""


def _printing(snap: Snapshot) -> bool:
    return snap.state == "printing" and snap.job is not None


async def watch(socket: Path, seconds: float, done: Path, start_timeout: float) -> list[Snapshot]:
    """Status snapshots from the control socket: up to ``start_timeout`` s for printing to
    start (homing at real time takes a while), then ``seconds`` of printing, or until the
    job is done."""
    snaps: list[Snapshot] = []
    started = asyncio.Event()

    async def consume() -> None:
        async with ControlClient(str(socket)) as client:
            async for item in client.subscribe():
                if "status" in item:
                    snaps.append(item["status"])
                    if _printing(item["status"]):
                        started.set()

    task = asyncio.create_task(consume())
    try:
        await asyncio.wait_for(started.wait(), timeout=start_timeout)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not task.done() and not any(done.glob("*")):
            await asyncio.sleep(0.2)
    except TimeoutError:
        pass
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, ControlError, OSError):
            await task
    return snaps


def summarise(model: Path, scale: float, snaps: list[Snapshot]) -> Lead:
    """Ready-ahead figures over the samples taken while printing.

    Samples of the last layer (nothing left to slice ahead) are left out.
    """
    lead = Lead(model=model.stem, faces=stl_faces(model), time_scale=scale)
    jobs = [s.job for s in snaps if _printing(s) and s.job is not None]
    jobs = [j for j in jobs if j.layer + 1 < j.layers]
    if not jobs:
        lead.note = "no printing status seen"
        return lead
    ready = [j.layers_ready_ahead for j in jobs]
    lead.samples = len(ready)
    lead.starved_samples = sum(1 for r in ready if r < 1)
    lead.starved_layers = sorted({j.layer for j in jobs if j.layers_ready_ahead < 1})
    lead.min_ready = min(ready)
    lead.mean_ready = sum(ready) / len(ready)
    lead.layers_printed = max(j.layer for j in jobs)
    lead.layers = jobs[-1].layers
    return lead


def measure(model: Path, scale: float, seconds: float, start_timeout: float,
            slice_process: bool = True) -> Lead:
    """Print ``model`` at time scale ``scale`` and watch its status for ``seconds``
    (``slice_process``: the daemon's ``[runner] slice_process``)."""
    with Daemon(DaemonSetup(time_scale=scale, settle_s=0.2,
                            slice_process=slice_process)) as daemon:
        daemon.wait_ready()
        sockets = [p for p in daemon.state.rglob("*") if p.is_socket()]
        daemon.drop(model)
        snaps = asyncio.run(watch(sockets[0], seconds, daemon.jobs / "done", start_timeout))
        lead = summarise(model, scale, snaps)
        if lead.note:
            states = ", ".join(sorted({s.state for s in snaps})) or "none"
            alive = "running" if daemon.alive() else f"exited: {daemon.log_tail()}"
            lead.note += f" (states seen: {states}; daemon {alive})"
    return lead


def table(rows: list[Lead]) -> str:
    """Markdown table of the measured windows."""
    lines = ["| model | faces | time scale | layer reached | status samples "
             "| samples with < 1 layer ready (at layers) | min ready ahead | mean ready ahead "
             "| note |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        mean = "-" if r.mean_ready is None else f"{r.mean_ready:.1f}"
        lines.append(f"| {r.model} | {r.faces:,} | {r.time_scale:g} "
                     f"| {r.layers_printed}/{r.layers} | {r.samples} "
                     f"| {r.starved_samples} ({', '.join(map(str, r.starved_layers)) or '-'}) "
                     f"| {'-' if r.min_ready is None else r.min_ready} | {mean} | {r.note} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the windows and print the table."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="bunny,dragon_100k,3DBenchy")
    p.add_argument("--models-dir", type=Path, default=MODELS)
    p.add_argument("--time-scales", default="1,0.05")
    p.add_argument("--seconds", type=float, default=60.0, help="watch window per print")
    p.add_argument("--start-timeout", type=float, default=180.0,
                   help="longest wait for printing to start (homing, first layer)")
    p.add_argument("--slice-in-daemon", action="store_true",
                   help="[runner] slice_process = false: every layer sliced in the daemon")
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args(argv)
    scales = [float(v) for v in args.time_scales.split(",") if v.strip()]
    rows = []
    for model in model_paths(args.models_dir, args.models):
        for scale in scales:
            rows.append(measure(model, scale, args.seconds, args.start_timeout,
                                not args.slice_in_daemon))
            print(f"  {rows[-1]}", file=sys.stderr)
    print(table(rows))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "lead_over_printer.json").write_text(json.dumps([asdict(r) for r in rows],
                                                                indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
