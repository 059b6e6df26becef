"""Where a `hostd slice` run's wall time goes, from the moment the process is started.

Each run is a fresh `python -m hostd slice MODEL` (the benchmark's settings, as
``bench/slice_vs_peers.py`` gives them) whose main process stamps, in wall time
since it was started and in its own CPU time: the interpreter up (``site`` and
the editable install's import hook included), the command line read, the slicer's
imports done, the plan made, the outlines cut (here, or half of them in a forked
child), the workers forked, the file's header extras (thumbnails, object labels:
made here while the workers slice), the first and the last layer back, and the
file written. Each task of layers the workers make is stamped too (start and end,
and its CPU time). The table gives the median of each stamp over the runs.

The stamps wrap the slicer's functions from outside (nothing of the project
changes); what they cost is some tens of microseconds a run. The import time of
each module is ``python -X importtime -m hostd slice ...``'s.

Usage (from the repository root):
    .venv/bin/python bench/slice_timeline.py --models v2_front_idler_left_lower --repeat 7
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.slice_ab import find_model
from bench.slice_vs_peers import BED_TOML, OUR_SETTINGS

# run in the measured process: stamps (wall ms since T0, CPU ms, label) written as JSON
# lines to the file named by TIMELINE_OUT when the command returns
_BOOT = r"""
import os, sys, time
T0 = float(os.environ["TIMELINE_T0"])
marks = []
def stamp(label):
    marks.append(((time.time() - T0) * 1e3, time.process_time() * 1e3, label))
stamp("interpreter up (site, import hook)")
import hostd.app.cli as cli
import hostd.app.commands.slice as command
stamp("command line module")
paused = command.collector_paused
import contextlib

def wrap(owner, name, before, after):
    real = getattr(owner, name)
    def wrapped(*args, **kwargs):
        if before: stamp(before)
        result = real(*args, **kwargs)
        if after: stamp(after)
        return result
    setattr(owner, name, wrapped)

def hooks():
    import slicer.forkslice as fs
    import slicer.output.gcodefile as gf
    import slicer.plan as sp
    from_file = sp.SlicePlan.from_file.__func__
    def made(cls, *args, **kwargs):
        stamp("imports done, model read")
        plan = from_file(cls, *args, **kwargs)
        stamp("plan made")
        return plan
    sp.SlicePlan.from_file = classmethod(made)
    wrap(sp.SlicePlan, "cut_away", "", "outline cut begun in a child")
    wrap(sp.SlicePlan, "cut_all", "", "outlines cut")
    wrap(fs.ForkedLayers, "__init__", "", "workers forked")
    wrap(fs.ForkedLayers, "close", "last layer back, workers let go", "workers reaped")
    wrap(gf, "header_extras", "header extras begun", "header extras made")
    wrap(gf, "copy_layers", "layers all back", "file written")
    layers = gf.iter_layer_texts
    def timed_layers(*args, **kwargs):
        first = True
        for layer in layers(*args, **kwargs):
            if first:
                stamp("first layer back")
                first = False
            yield layer
    gf.iter_layer_texts = timed_layers
    make = gf._layer_texts
    def task(plan, lo, hi, labels=None):
        start, cpu = (time.time() - T0) * 1e3, time.process_time()
        out = make(plan, lo, hi, labels)
        record = {"task": [lo, hi], "pid": os.getpid(), "start": start,
                  "end": (time.time() - T0) * 1e3, "cpu": (time.process_time() - cpu) * 1e3}
        with open(os.environ["TIMELINE_OUT"] + ".tasks", "a") as fh:
            fh.write(json.dumps(record) + "\n")
        return out
    gf._layer_texts = task

@contextlib.contextmanager
def hooked():
    with paused():
        yield
    if "slicer.output.gcodefile" in sys.modules and not marks[-1][2].startswith("args"):
        stamp("args read, slicer imported")
        hooks()
command.collector_paused = hooked
import json
sys.argv = ["hostd", *sys.argv[1:]]
code = cli.main()
stamp("command returned")
with open(os.environ["TIMELINE_OUT"], "w") as fh:
    for mark in marks:
        fh.write(json.dumps(mark) + "\n")
sys.stdout.flush()
os._exit(code)
"""


def one_run(model: Path, folder: Path, config: Path) -> tuple[list, list]:
    """One measured `hostd slice`: its stamps and its tasks."""
    out = folder / "stamps.jsonl"
    for path in (out, Path(f"{out}.tasks")):
        path.unlink(missing_ok=True)
    cmd = [sys.executable, "-c", _BOOT, "slice", str(model), "-o", str(folder / "out.gcode"),
           "--quiet", "--config", str(config)]
    for setting in OUR_SETTINGS:
        cmd += ["--set", setting]
    env = dict(os.environ, TIMELINE_OUT=str(out), TIMELINE_T0=repr(time.time()))
    subprocess.run(cmd, env=env, check=True, stdout=subprocess.DEVNULL)
    marks = [json.loads(line) for line in out.read_text().splitlines()]
    tasks_file = Path(f"{out}.tasks")
    tasks = [json.loads(line) for line in tasks_file.read_text().splitlines()] \
        if tasks_file.exists() else []
    return marks, tasks


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", required=True, help="corpus, shared or real model names, a,b,...")
    p.add_argument("--repeat", type=int, default=7)
    args = p.parse_args(argv)
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="slice-timeline-") as tmp:
        folder = Path(tmp)
        config = folder / "printer.toml"
        config.write_text(BED_TOML)
        for name in [m.strip() for m in args.models.split(",") if m.strip()]:
            runs = [one_run(find_model(name), folder, config) for _ in range(args.repeat)]
            print(f"\n{name}, medians of {args.repeat} runs\n")
            print("| stamp | wall since start (ms) | CPU of this process (ms) |")
            print("|---|---|---|")
            labels = [label for _w, _c, label in runs[0][0]]
            for k, label in enumerate(labels):
                got = [marks[k] for marks, _ in runs if len(marks) > k and marks[k][2] == label]
                wall = statistics.median(m[0] for m in got)
                cpu = statistics.median(m[1] for m in got)
                print(f"| {label} | {wall:.1f} | {cpu:.1f} |")
            tasks: dict[tuple[int, int], list[dict]] = {}
            for _, run_tasks in runs:
                for t in run_tasks:
                    tasks.setdefault(tuple(t["task"]), []).append(t)
            if tasks:
                print("\n| task (layers) | begun (ms) | ended (ms) | CPU (ms) |")
                print("|---|---|---|---|")
                for (lo, hi), made in sorted(tasks.items()):
                    print(f"| {lo}-{hi - 1} | {statistics.median(t['start'] for t in made):.1f} | "
                          f"{statistics.median(t['end'] for t in made):.1f} | "
                          f"{statistics.median(t['cpu'] for t in made):.1f} |")
    print(f"\nload average at end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
