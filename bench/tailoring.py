"""Built-in analysis and tailoring: analysis time and peak RSS, `hostd tailor`, first extrusion.

Measures, each in a fresh process:
  * the mesh convergence of a cantilever (tip deflection against Timoshenko beam theory);
  * the analysis alone (voxelise, assemble, solve, stress) of the dogbone under its
    load case and of the bunny under the case below, at the default mesh size: wall
    time and the process's peak resident memory;
  * the whole `hostd tailor examples/dogbone` (empty analysis cache);
  * drop-to-first-extrusion of a stress job (dogbone.stl with dogbone.load.toml) in a
    fresh daemon on the simulated printer.
Targets: dogbone analysis < 10 s, whole example < 60 s, bunny peak RSS < 500 MB,
stress job's first extrusion < 1 s after the drop settles.

With --validate, instead: the solver and the road-aware predictions against closed
forms, CalculiX and the roads resolved in the mesh (bench/tailoring_validate.py).

Usage (from the repository root):
    .venv/bin/python bench/tailoring.py [--skip-daemon] [--json OUT.json]
    .venv/bin/python bench/tailoring.py --validate [--gcodes OUT] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ROOT = Path(__file__).resolve().parents[1]
DOGBONE = ROOT / "examples" / "dogbone"
BUNNY = ROOT.parent / "shared" / "models" / "bunny.stl"
# the bunny sits on its base; its head and ears (z above 52 mm) are pushed sideways and down
BUNNY_CASE = """
[[fixed]]
box = [[0, 0, 0], [62.3, 48.3, 0.5]]
[[force]]
box = [[0, 0, 52], [62.3, 48.3, 61.8]]
newtons = [20, 0, -50]
"""
SIZES = (2.5, 1.25, 0.0, 0.625, 0.5)  # 0: the default


def child_analysis(model: str, load: str, size: float) -> dict:
    """In a fresh process: analyse ``model`` under ``load``; time and peak RSS."""
    from slicer.fea.field import analyse_arrays
    from slicer.fea.loadcase import read_load_case
    from slicer.input.mesh import read_stl

    started = time.perf_counter()
    vertices, faces = read_stl(model)
    solution = analyse_arrays(vertices, faces, read_load_case(load), size)
    return {
        "seconds": time.perf_counter() - started,
        "solve_s": solution.seconds,
        "peak_rss_mb": peak_rss_mb(),
        "elements": len(solution.mesh.cells),
        "cell_mm": [round(float(c), 3) for c in solution.mesh.grid.cell],
        "iterations": solution.iterations,
        "peak_mpa": float(solution.von_mises.max()),
    }


def peak_rss_mb() -> float:
    """This process's peak resident memory, MB: VmHWM, which exec resets (ru_maxrss keeps
    the parent's peak when the child was forked from a big parent)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_child(*args: str) -> dict:
    """This script with ``args`` in a new interpreter; its JSON answer."""
    done = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=900, check=False)
    if done.returncode != 0:
        raise RuntimeError(done.stderr.strip().splitlines()[-1] if done.stderr else "failed")
    return json.loads(done.stdout.strip().splitlines()[-1])


def convergence() -> list[dict]:
    """Cantilever 100 x 10 x 10 mm, 10 N at the tip: deflection / theory per mesh size."""
    import numpy as np
    import trimesh

    from slicer.fea.field import analyse_arrays
    from slicer.fea.loadcase import parse_load_case

    length, side, force, e, nu = 100.0, 10.0, 10.0, 2200.0, 0.35
    beam = trimesh.creation.box((length, side, side))
    beam.apply_translation([length / 2, side / 2, side / 2])
    case = parse_load_case(
        f"[[fixed]]\nbox = [[0, 0, 0], [0, {side}, {side}]]\n"
        f"[[force]]\nbox = [[{length}, 0, 0], [{length}, {side}, {side}]]\n"
        f"newtons = [0, 0, -{force}]\n")
    inertia = side**4 / 12.0
    theory = force * length**3 / (3 * e * inertia) + force * length / (
        5 / 6 * e / (2 * (1 + nu)) * side * side)
    rows = []
    for size in SIZES:
        solution = analyse_arrays(beam.vertices, beam.faces, case, size)
        tip = solution.mesh.points[:, 0] > length - 1e-6
        deflection = -float(np.mean(solution.displacement[tip, 2]))
        rows.append({"size_mm": round(float(solution.mesh.grid.cell[0]), 3),
                     "default": size == 0.0, "elements": len(solution.mesh.cells),
                     "deflection_mm": deflection, "ratio": deflection / theory,
                     "iterations": solution.iterations, "seconds": solution.seconds})
    return rows


def tailor_example() -> dict:
    """The whole `hostd tailor examples/dogbone`, analysis cache empty."""
    with tempfile.TemporaryDirectory(prefix="bench-tailor-") as tmp:
        env = {**os.environ, "XDG_CACHE_HOME": tmp, "PYTHONPATH": str(ROOT)}
        started = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "hostd", "tailor", str(DOGBONE), "-o", f"{tmp}/out"],
            capture_output=True, text=True, env=env, cwd=ROOT, timeout=1800, check=False)
        seconds = time.perf_counter() - started
    return {"seconds": seconds, "ok": done.returncode == 0,
            "report": done.stdout if done.returncode == 0 else done.stderr}


def stress_drop(with_load: bool = True, timeout: float = 300.0, reprint: bool = False) -> dict:
    """Drop dogbone.load.toml (unless not ``with_load``) then dogbone.stl into a fresh
    daemon; settled -> first extrusion. With ``reprint``, the job is printed once
    first (its analysis cached) and the figure is the second drop's."""
    from bench.daemonproc import Daemon, DaemonSetup
    from bench.drop_to_extrusion import first_extrusion
    from bench.gcodeparse import is_extruding_line

    setup = DaemonSetup()
    with Daemon(setup) as daemon:
        daemon.wait_ready()

        def drop() -> float:
            if with_load:
                hidden = daemon.jobs / ".dogbone.load.toml.part"
                shutil.copyfile(DOGBONE / "dogbone.load.toml", hidden)
                os.replace(hidden, daemon.jobs / "dogbone.load.toml")
            return daemon.drop(DOGBONE / "dogbone.stl")

        written = drop()
        seen, note = first_extrusion(daemon, "dogbone.stl", timeout)
        if reprint and seen is not None:
            seen, note = None, "the first print did not finish"
            deadline = time.monotonic() + timeout
            summaries = daemon.jobs / "done"
            while time.monotonic() < deadline and not list(summaries.glob("*summary*")):
                time.sleep(0.05)
            log = daemon.executed_log()
            if log is not None and list(summaries.glob("*summary*")):
                with open(log, encoding="utf-8", errors="replace") as handle:
                    handle.seek(0, os.SEEK_END)
                    written = drop()
                    pending = ""
                    while time.monotonic() < deadline and seen is None:
                        pending += handle.read()
                        *lines, pending = pending.split("\n")
                        if any(is_extruding_line(line) for line in lines):
                            seen, note = time.perf_counter(), ""
                        time.sleep(0.002)
    if seen is None:
        return {"settled_to_extrusion_s": None, "note": note}
    return {"settled_to_extrusion_s": seen - written - setup.settle_s, "note": note}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--child", nargs=3, metavar=("MODEL", "LOAD", "SIZE"), help=argparse.SUPPRESS)
    p.add_argument("--skip-daemon", action="store_true", help="no drop-to-extrusion run")
    p.add_argument("--only", choices=("convergence", "analysis", "tailor", "drop"),
                   help="run one part only")
    p.add_argument("--json", type=Path, metavar="OUT", help="also write the figures as JSON")
    p.add_argument("--validate", action="store_true",
                   help="compare with closed forms, CalculiX and resolved roads, print errors")
    p.add_argument("--gcodes", type=Path, metavar="DIR",
                   help="with --validate: also the gages of hostd tailor's prints in DIR")
    args = p.parse_args(argv)
    if args.validate:
        from bench.tailoring_validate import validate

        figures = validate(args.gcodes)
        if args.json:
            args.json.write_text(json.dumps(figures, indent=2))
        return 0
    if args.child:
        print(json.dumps(child_analysis(args.child[0], args.child[1], float(args.child[2]))))
        return 0
    figures: dict = {"loadavg_before": os.getloadavg()}

    def wanted(part: str) -> bool:
        return args.only in (None, part)

    if wanted("convergence"):
        _convergence(figures)
    if wanted("analysis"):
        _analyses(figures)
    if wanted("tailor"):
        figures["tailor"] = tailor_example()
        print(f"hostd tailor examples/dogbone: {figures['tailor']['seconds']:.1f} s "
              f"({'ok' if figures['tailor']['ok'] else 'FAILED'})")
        print("  " + figures["tailor"]["report"].strip().replace("\n", "\n  "))
    if wanted("drop") and not args.skip_daemon:
        labels = {"linear_drop": "the same model without its load case",
                  "stress_drop": "stress job",
                  "stress_drop_reprint": "the stress job printed again (analysis cached)"}
        for name, with_load, reprint in (("linear_drop", False, False),
                                        ("stress_drop", True, False),
                                        ("stress_drop_reprint", True, True)):
            figures[name] = stress_drop(with_load, reprint=reprint)
            latency = figures[name]["settled_to_extrusion_s"]
            label = labels[name]
            print(f"{label}, settled -> first extrusion: "
                  + (f"{latency:.2f} s" if latency is not None else figures[name]["note"]))
    figures["loadavg_after"] = os.getloadavg()
    print(f"load average before/after: {figures['loadavg_before'][0]:.1f} / "
          f"{figures['loadavg_after'][0]:.1f} on {os.cpu_count()} cores")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    return 0


def _convergence(figures: dict) -> None:
    print("cantilever 100 x 10 x 10 mm, tip deflection / Timoshenko beam theory")
    print("  mesh mm  elements  ratio   iterations  solve s")
    figures["convergence"] = convergence()
    for row in figures["convergence"]:
        mark = " (default)" if row["default"] else ""
        print(f"  {row['size_mm']:7.3f}  {row['elements']:8d}  {row['ratio']:.4f}  "
              f"{row['iterations']:10d}  {row['seconds']:7.2f}{mark}")


def _analyses(figures: dict) -> None:
    with tempfile.TemporaryDirectory(prefix="bench-fea-") as tmp:
        bunny_load = Path(tmp) / "bunny.load.toml"
        bunny_load.write_text(BUNNY_CASE)
        cases = {"dogbone": (DOGBONE / "dogbone.stl", DOGBONE / "dogbone.load.toml")}
        if BUNNY.is_file():
            cases["bunny"] = (BUNNY, bunny_load)
        for name, (model, load) in cases.items():
            row = run_child("--child", str(model), str(load), "0")
            figures[f"analysis_{name}"] = row
            print(f"analysis {name}: {row['seconds']:.2f} s (solve {row['solve_s']:.2f} s, "
                  f"{row['iterations']} iterations), {row['elements']} elements of "
                  f"{row['cell_mm']} mm, peak RSS {row['peak_rss_mb']:.0f} MB")


if __name__ == "__main__":
    sys.exit(main())
