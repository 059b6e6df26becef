"""`hostd slice` of this tree against another version's, alternately: wall times and bytes.

For every model the two versions slice in turn (A, B, A, B, ...: load on the
shared machine hits both alike), each a cold `hostd slice` process with the
peers' settings (``bench/slice_vs_peers.py``), and the table gives each one's
median wall time, the ratio, and whether the two G-code files are the same
bytes (thumbnails, object labels and M73 lines included); also the median CPU
time (user + system, workers included), which a loaded machine disturbs less
than the wall time. ``--all`` takes
every model: the generated corpus, the shared models and the real parts of
``../shared/models/real/`` (read from there). The other version
is an exported tree (``git archive REF | tar -x -C DIR``), run with
``PYTHONPATH`` pointing at it; its modules are compiled first, as this tree's
are (``make .venv/.installed``). ``--variant`` adds settings (e.g.
``gcode.arcs=on``), ``--default`` slices with the defaults instead of the
peers' settings.

Usage (from the repository root):
    git archive main | tar -x -C /tmp/main-tree
    .venv/bin/python bench/slice_ab.py --other /tmp/main-tree --repeat 3 \\
        --models cube20_xyz,text_standing [--variant gcode.arcs=on] [--check-only]
    .venv/bin/python bench/slice_ab.py --other /tmp/main-tree --all --check-only
"""

from __future__ import annotations

import argparse
import compileall
import filecmp
import os
import resource
import statistics
import sys
import tempfile
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.layer_cpu import CORPUS, SHARED, model_path
from bench.measure import run_measured
from bench.slice_vs_peers import BED_TOML, OUR_SETTINGS

ROOT = Path(__file__).resolve().parents[1]


def command(model: Path, out: Path, config: Path, settings: list[str], extra: list[str]
            ) -> list[str]:
    """The `hostd slice` command line of one run: ``python -m hostd``, so each version
    starts and ends as its own ``hostd/__main__.py`` does (the console script in the
    environment is one version's only)."""
    cmd = [sys.executable, "-m", "hostd", "slice", str(model), "-o", str(out), "--quiet",
           "--config", str(config)]
    for setting in [*settings, *extra]:
        cmd += ["--set", setting]
    return cmd


# the real parts: printed parts as their designers exported them (GPL data, read from there)
REAL = SHARED / "real"


def find_model(name: str) -> Path:
    """The corpus or shared model ``name``, else the real part of that name."""
    real = REAL / f"{name}.stl"
    if not (CORPUS / f"{name}.stl").exists() and not (SHARED / f"{name}.stl").exists() \
            and real.exists():
        return real
    return model_path(name)


def every_model() -> list[str]:
    """The names of every model ``--all`` slices: the generated corpus (when built), the
    shared models and the real parts (when their folder is there)."""
    names = [path.stem for folder in (CORPUS, SHARED, REAL)
             for path in sorted(folder.glob("*.stl"))]
    return list(dict.fromkeys(names))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--other", type=Path, required=True, help="exported tree of the other version")
    p.add_argument("--models", default="", help="corpus, shared or real model names, a,b,...")
    p.add_argument("--all", action="store_true",
                   help="every model: the corpus, the shared models and the real parts")
    p.add_argument("--repeat", type=int, default=3, help="runs of each version per model")
    p.add_argument("--variant", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting added to the peers' settings (repeatable)")
    p.add_argument("--default", action="store_true", help="the default settings, not the peers'")
    p.add_argument("--check-only", action="store_true", help="one run each: bytes only")
    p.add_argument("--timeout", type=float, default=600.0)
    args = p.parse_args(argv)
    names = [m.strip() for m in args.models.split(",") if m.strip()]
    if args.all:
        names += [name for name in every_model() if name not in names]
    if not names:
        p.error("name models with --models, or --all")
    for package in ("hostd", "slicer", "drivers"):
        compileall.compile_dir(args.other / package, quiet=1)
        compileall.compile_dir(ROOT / package, quiet=1)
    trees = {"this": ROOT, "other": args.other.resolve()}
    settings = [] if args.default else list(OUR_SETTINGS)
    repeat = 1 if args.check_only else args.repeat
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    print("| model | this (s) | other (s) | this / other | CPU this (s) | CPU other (s) | "
          "CPU this / other | same bytes |")
    print("|---|---|---|---|---|---|---|---|")
    failures = 0
    with tempfile.TemporaryDirectory(prefix="slice-ab-") as tmp:
        config = Path(tmp) / "printer.toml"
        config.write_text(BED_TOML)
        for name in names:
            model = find_model(name)
            walls: dict[str, list[float]] = {"this": [], "other": []}
            cpus: dict[str, list[float]] = {"this": [], "other": []}
            outs = {k: Path(tmp) / f"{name}.{k}.gcode" for k in trees}
            refusals: dict[str, str] = {}
            for _ in range(repeat):
                for key, tree in trees.items():
                    env = dict(os.environ, PYTHONPATH=str(tree))
                    cmd = command(model, outs[key], config, settings, args.variant)
                    before = resource.getrusage(resource.RUSAGE_CHILDREN)
                    result = run_measured(cmd, timeout=args.timeout, env=env, cwd=tmp)
                    after = resource.getrusage(resource.RUSAGE_CHILDREN)
                    cpus[key].append(after.ru_utime + after.ru_stime
                                     - before.ru_utime - before.ru_stime)
                    if result.returncode == 2:  # a model refused (a usage error): its reason
                        refusals[key] = result.stderr.strip().replace(str(tree), "")
                    elif not result.ok:
                        print(f"{name}: {key} failed: {result.reason()}", file=sys.stderr)
                        return 1
                    walls[key].append(result.wall_s)
            if refusals:  # refused by either: the same when both refuse it alike
                same = len(refusals) == 2 and refusals["this"] == refusals["other"]
                failures += not same
                reason = refusals.get("this") or refusals.get("other") or ""
                print(f"| {name} | refused | refused | - | - | - | - | "
                      f"{'yes (both refuse it)' if same else 'NO'}: {reason[:80]} |", flush=True)
                continue
            same = filecmp.cmp(outs["this"], outs["other"], shallow=False)
            failures += not same
            a, b = statistics.median(walls["this"]), statistics.median(walls["other"])
            ca, cb = statistics.median(cpus["this"]), statistics.median(cpus["other"])
            print(f"| {name} | {a:.2f} | {b:.2f} | {a / b:.2f} | {ca:.2f} | {cb:.2f} | "
                  f"{ca / cb:.2f} | {'yes' if same else 'NO'} |", flush=True)
    print(f"load average at end: {os.getloadavg()[0]:.2f}")
    if failures:
        print(f"{failures} of {len(names)} models not the same bytes", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
