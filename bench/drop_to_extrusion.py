"""Daemon latency and footprint: drop-to-first-extrusion, idle CPU, peak RSS while printing.

For each model a fresh `hostd run` (simulated printer, instant motion, heating skipped,
the slicing settings of the peer comparison), once its log says its slicer warmed up
(the last step of its start-up), gets the model dropped into its job
folder; the latency runs from the moment the file is settled (fully written, then
``settle_s`` of stability) to the first extruding move (a G0/G1 with X or Y and E > 0)
in the simulated printer's executed-line log. Next to it, CuraEngine's whole-model
slicing time on the same model (a batch slicer writes no G-code before it has sliced
everything). Then the idle daemon's CPU use over 60 s and its peak resident memory
while printing the largest models to the end.

With ``--corpus`` the drops are the shared models, the real parts of
``../shared/models/real/`` (skipped when absent) and the generated corpus
(``bench/corpus.py``), and each row says whether the first extrusion came at least
10x sooner than CuraEngine's whole slice where CuraEngine needs 0.5 s or more.
``--print-model large_sphere_3m`` prints the 3.03M-triangle memory case.

Usage (from the repository root):
    .venv/bin/python bench/drop_to_extrusion.py [--models bunny,dragon_100k] [--repeat 3]
    .venv/bin/python bench/drop_to_extrusion.py --corpus --idle-s 0 --print-model ''
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import proctree
from bench.daemonproc import Daemon, DaemonSetup
from bench.gcodeparse import is_extruding_line
from bench.peers import curaengine
from bench.slice_vs_peers import (
    MODELS,
    OUT,
    SCALE_SOURCE,
    corpus_paths,
    make_scale_model,
    model_paths,
    stl_faces,
)

_POLL_S = 0.005
SCALE_NAME = "bunny_x16"
_PLAN_LOG = re.compile(r"whole-model pass ([0-9.]+) s")
LARGE_NAME = "large_sphere_3m"
# the lead asked for: first extrusion this many times sooner than CuraEngine's whole
# slice, on every model CuraEngine needs at least LEAD_FROM_S for
LEAD_TARGET = 10.0
LEAD_FROM_S = 0.5


@dataclass
class Latency:
    """Drop-to-first-extrusion of one model."""

    model: str
    faces: int
    settled_to_extrusion_s: float | None = None  # median
    dropped_to_extrusion_s: float | None = None  # median, settle time included
    plan_s: float | None = None  # the daemon's whole-model pass (from its log), median
    cura_slice_s: float | None = None  # CuraEngine whole-model slicing, median
    note: str = ""

    @property
    def lead(self) -> float | None:
        """How many times sooner than CuraEngine's whole slicing the first extrusion comes."""
        if self.settled_to_extrusion_s and self.cura_slice_s:
            return self.cura_slice_s / self.settled_to_extrusion_s
        return None


def first_extrusion(daemon: Daemon, name: str, timeout: float) -> tuple[float | None, str]:
    """Poll the executed-line log for the first extruding move; (time, note)."""
    deadline = time.monotonic() + timeout
    handle = None
    pending = ""
    try:
        while time.monotonic() < deadline:
            if handle is None:
                path = daemon.executed_log()
                if path is not None:
                    handle = open(path, encoding="utf-8", errors="replace")  # noqa: SIM115
            if handle is not None:
                pending += handle.read()
                lines = pending.split("\n")
                pending = lines.pop()
                for line in lines:
                    if is_extruding_line(line):
                        return time.perf_counter(), ""
            reason = daemon.failure(name)
            if reason is not None:
                return None, f"refused: {reason}"
            if not daemon.alive():
                code = daemon.proc.returncode if daemon.proc else None
                return None, f"daemon exited with status {code}; last log line: {daemon.log_tail()}"
            time.sleep(_POLL_S)
    finally:
        if handle is not None:
            handle.close()
    where = "no executed-line log under the state folder" if handle is None else "none seen"
    return None, f"no extruding move within {timeout:.0f} s ({where})"


@dataclass(frozen=True)
class Drop:
    """One drop: latencies in s (None if no extrusion came) and the daemon's own figure."""

    settled_s: float | None
    dropped_s: float | None
    plan_s: float | None  # the whole-model pass, as the daemon logs it
    note: str


def measure_latency(model: Path, setup: DaemonSetup, timeout: float) -> Drop:
    """One drop of ``model`` into a fresh daemon."""
    with Daemon(setup) as daemon:
        daemon.wait_ready()
        daemon.wait_warm()  # a drop lands on a daemon that has finished starting up
        written = daemon.drop(model)
        seen, note = first_extrusion(daemon, model.name, timeout)
        found = _PLAN_LOG.search(daemon.log.read_text(errors="replace"))
    plan_s = float(found.group(1)) if found else None
    if seen is None:
        return Drop(None, None, plan_s, note)
    return Drop(seen - written - setup.settle_s, seen - written, plan_s, note)


def cura_time(model: Path, repeat: int, timeout: float) -> float | None:
    """Median CuraEngine whole-model slicing time, s (None if CuraEngine is unavailable)."""
    peer = curaengine()
    if peer is None:
        return None
    times = []
    with tempfile.TemporaryDirectory(prefix="bench-cura-") as tmp:
        for _ in range(repeat):
            result = peer.slice(model, Path(tmp) / "out.gcode", timeout)
            if result.ok:
                times.append(result.wall_s)
    return statistics.median(times) if times else None


def idle_cpu(setup: DaemonSetup, seconds: float) -> float:
    """CPU use of an idle daemon (empty job folder), percent of one core over ``seconds``."""
    with Daemon(setup) as daemon:
        daemon.wait_ready()
        time.sleep(2.0)  # start-up work done
        start_cpu, start = proctree.cpu_seconds(daemon.pid), time.monotonic()
        time.sleep(seconds)
        used = proctree.cpu_seconds(daemon.pid) - start_cpu
        elapsed = time.monotonic() - start
    return 100.0 * used / elapsed


@dataclass
class PrintMemory:
    """Memory while printing one model to the end."""

    model: str
    faces: int
    daemon_hwm_mb: float = 0.0  # VmHWM of the daemon process
    tree_peak_mb: float = 0.0  # highest sampled PSS of the daemon and its children together
    print_s: float | None = None  # drop to job done
    note: str = ""


def print_memory(model: Path, setup: DaemonSetup, timeout: float) -> PrintMemory:
    """Print ``model`` to the end (or ``timeout``) and record peak memory."""
    result = PrintMemory(model=model.stem, faces=stl_faces(model))
    with Daemon(setup) as daemon:
        daemon.wait_ready()
        written = daemon.drop(model)
        deadline = time.monotonic() + timeout
        done = daemon.jobs / "done"
        while time.monotonic() < deadline and daemon.alive():
            result.tree_peak_mb = max(result.tree_peak_mb, proctree.tree_pss_mb(daemon.pid))
            result.daemon_hwm_mb = proctree.status_kb(daemon.pid, "VmHWM") * 1024 / 1e6
            if any(done.glob(f"{model.stem}*.gcode")):
                result.print_s = time.perf_counter() - written
                break
            reason = daemon.failure(model.name)
            if reason is not None:
                result.note = f"failed: {reason}"
                break
            time.sleep(0.1)
        else:
            result.note = (f"not finished within {timeout:.0f} s" if daemon.alive()
                           else f"daemon exited: {daemon.log_tail()}")
    return result


def print_models(folder: Path, names: str) -> list[Path]:
    """The models to print for peak RSS: shared models by name, or the scale model."""
    from bench.corpus import large_model

    wanted = [n.strip() for n in names.split(",") if n.strip()]
    paths = [make_scale_model(folder / SCALE_SOURCE) for n in wanted if n == SCALE_NAME]
    paths += [large_model() for n in wanted if n == LARGE_NAME]
    shared = ",".join(n for n in wanted if n not in (SCALE_NAME, LARGE_NAME))
    return (model_paths(folder, shared) if shared else []) + paths


def _median(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return statistics.median(present) if present else None


def latency_table(rows: list[Latency]) -> str:
    """Markdown table of the latencies."""
    lines = ["| model | faces | settled -> first extrusion | dropped -> first extrusion "
             "| of which whole-model pass | CuraEngine whole slicing | CuraEngine / ours | note |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        def s(v: float | None) -> str:
            return "-" if v is None else f"{v:.3f} s"
        lead = "-" if r.lead is None else f"{r.lead:.1f}x"
        if r.lead is not None and r.cura_slice_s and r.cura_slice_s >= LEAD_FROM_S:
            lead += " ok" if r.lead >= LEAD_TARGET else " **short**"
        lines.append(f"| {r.model} | {r.faces:,} | {s(r.settled_to_extrusion_s)} "
                     f"| {s(r.dropped_to_extrusion_s)} | {s(r.plan_s)} "
                     f"| {s(r.cura_slice_s)} | {lead} | {r.note} |")
    return "\n".join(lines)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="", help="comma-separated model names (default: all)")
    p.add_argument("--models-dir", type=Path, default=MODELS)
    p.add_argument("--repeat", type=int, default=1, help="drops per model (medians if > 1)")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per drop")
    p.add_argument("--settle-s", type=float, default=0.5)
    p.add_argument("--baud", type=int, default=250000, help="simulated wire speed (0 = no limit)")
    p.add_argument("--idle-s", type=float, default=60.0, help="idle CPU window, s (0 = skip)")
    p.add_argument("--print-model", default=f"3DBenchy,{SCALE_NAME}",
                   help="models printed to the end for peak RSS, comma-separated; "
                        f"{SCALE_NAME} is the ~1.1M-face subdivided bunny ('' = skip)")
    p.add_argument("--print-timeout", type=float, default=900.0)
    p.add_argument("--no-cura", action="store_true", help="skip CuraEngine's timings")
    p.add_argument("--slice-in-daemon", action="store_true",
                   help="[runner] slice_process = false: every layer sliced in the daemon")
    p.add_argument("--out", type=Path, default=OUT)
    p.add_argument("--corpus", action="store_true",
                   help="drop the shared models and the generated corpus")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the daemon benchmarks and print the results."""
    args = parse_args(argv)
    setup = DaemonSetup(settle_s=args.settle_s, baud=args.baud,
                        slice_process=not args.slice_in_daemon)
    rows: list[Latency] = []
    models = (corpus_paths(args.models_dir, args.models) if args.corpus
              else model_paths(args.models_dir, args.models))
    for model in models:
        row = Latency(model=model.stem, faces=stl_faces(model))
        drops = [measure_latency(model, setup, args.timeout) for _ in range(args.repeat)]
        good = [d for d in drops if d.settled_s is not None and d.dropped_s is not None]
        notes = [d.note for d in drops if d.note]
        plans = [d.plan_s for d in drops if d.plan_s is not None]
        row.settled_to_extrusion_s = _median([d.settled_s for d in good])
        row.dropped_to_extrusion_s = _median([d.dropped_s for d in good])
        row.plan_s = _median(plans)
        if notes:
            row.note = f"{len(notes)} of {args.repeat} drops failed, first: {notes[0]}"
        if not args.no_cura and model.stem != "bad_triangle_soup":
            row.cura_slice_s = cura_time(model, args.repeat, args.timeout)
        print(f"  {row.model:18s} {row.settled_to_extrusion_s} {row.cura_slice_s} {row.note}",
              file=sys.stderr)
        rows.append(row)
    results: dict[str, object] = {"setup": asdict(setup), "latency": [asdict(r) for r in rows]}
    print(latency_table(rows))
    short = [r.model for r in rows if r.lead is not None and r.cura_slice_s
             and r.cura_slice_s >= LEAD_FROM_S and r.lead < LEAD_TARGET]
    print(f"\nfirst extrusion under {LEAD_TARGET:g}x sooner than CuraEngine (where it needs "
          f">= {LEAD_FROM_S:g} s): {', '.join(short) if short else 'none'}")
    if args.idle_s > 0:
        idle = idle_cpu(setup, args.idle_s)
        results["idle_cpu_percent"] = idle
        print(f"\nidle daemon: {idle:.2f} % of one core over {args.idle_s:.0f} s")
    memories = []
    for model in print_models(args.models_dir, args.print_model):
        memory = print_memory(model, DaemonSetup(settle_s=args.settle_s, baud=0,
                                                 slice_process=not args.slice_in_daemon),
                              args.print_timeout)
        memories.append(asdict(memory))
        took = "-" if memory.print_s is None else f"{memory.print_s:.1f} s"
        size_mb = model.stat().st_size / 1e6
        print(f"printing {memory.model} ({memory.faces:,} faces, {size_mb:.1f} MB, unlimited "
              f"wire): daemon peak RSS (VmHWM) {memory.daemon_hwm_mb:.0f} MB (target under "
              f"{2 * size_mb + 100:.0f} MB = 2x the file + 100 MB), daemon and children together "
              f"(PSS) {memory.tree_peak_mb:.0f} MB, drop to done {took} {memory.note}")
    results["print_memory"] = memories
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "drop_to_extrusion.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
