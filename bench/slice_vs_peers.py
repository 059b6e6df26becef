"""Whole-model slicing, `hostd slice` against PrusaSlicer and CuraEngine, in one run.

For every model of the shared model folder it slices with all three at the same
settings (runs alternate, so load on the shared machine hits all alike) and prints one
row per model: wall-time ratios ours/peer, peak RSS, layer counts, filament length
ratio against PrusaSlicer, and the mean per-layer IoU of the outer wall against
PrusaSlicer's. Then the scale case: the bunny subdivided twice (~1.1M faces), ours
against CuraEngine.

With ``--corpus`` it slices the shared models, the real parts of
``../shared/models/real/`` (CAD exports of printed parts; skipped when absent)
and the generated corpus (``bench/corpus.py``) instead, and prints one row per
model with every target checked (time against the faster peer, filament, outer
wall), why where one is missed, and the worst ratio.

Usage (from the repository root):
    .venv/bin/python bench/slice_vs_peers.py [--repeat 3] [--models bunny,cube20_xyz]
    .venv/bin/python bench/slice_vs_peers.py --corpus [--models gear,vase_twisted]
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import statistics
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import corpus_table, gcodeparse
from bench.measure import RunResult, ensure_gnu_time, machine_speed, run_measured, speed_line
from bench.peers import CACHE, Peer, available_peers

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "models"
# the shared models' folder of real parts: printed parts as their designers exported them
REAL = "real"
OUT = ROOT / "bench" / "out"

# hostd slicing settings equal to the peers' (slicer/settings.py keys)
OUR_SETTINGS = (
    "layer_height=0.2", "first_layer_height=0.2", "line_width=0.4", "perimeters=2",
    "top_layers=3", "bottom_layers=3", "infill.field=\"linear\"", "infill.density=0.2",
    "support.enabled=false", "filament_diameter=1.75", "skip_heating=true",
)
BED_TOML = "[printer]\nbed = [200, 200, 200]\n"
SCALE_SOURCE = "bunny.stl"


@dataclass
class Runner:
    """One slicer as the benchmark runs it."""

    name: str
    peer: Peer | None = None  # None: hostd itself

    def run(self, model: Path, out: Path, timeout: float, config: Path) -> RunResult:
        """Slice ``model`` into ``out``, measured."""
        if self.peer is not None:
            return self.peer.slice(model, out, timeout)
        return run_measured(ours_command(model, out, config), timeout=timeout)


@dataclass
class Measured:
    """One slicer on one model: medians over the repeats and the G-code figures."""

    ok: bool = False
    reason: str = ""
    wall_s: float | None = None
    peak_rss_mb: float | None = None
    layers: int | None = None
    filament_mm: float | None = None
    runs: list[float] = field(default_factory=list)
    cpu_s: float | None = None  # median CPU time (user + system, every process of the run)


@dataclass
class Row:
    """Everything measured for one model."""

    model: str
    faces: int
    results: dict[str, Measured]
    iou_vs_prusa: float | None = None  # ours against PrusaSlicer, all layers
    iou_vs_prusa_common: float | None = None  # layers where both have an outer wall
    iou_vs_cura: float | None = None  # ours against CuraEngine, all layers
    worst_layers_vs_prusa: list[tuple[float, float]] = field(default_factory=list)  # (z, IoU)
    offset_vs_prusa: tuple[float, float] | None = None  # mm moved to align ours on PrusaSlicer's
    iou_cura_vs_prusa: float | None = None  # the two peers against each other (reference)


def write_bytecode() -> None:
    """Compile hostd's modules once, as an installed package has them: with
    PYTHONDONTWRITEBYTECODE set (as on the project's machines) a source checkout
    would compile them anew in every run, 0.2-0.3 s of each small model's time."""
    import compileall

    root = Path(__file__).resolve().parents[1]
    for package in ("hostd", "slicer", "drivers"):
        compileall.compile_dir(root / package, quiet=1)


def hostd_executable() -> list[str]:
    """How to call `hostd`: the console script beside this interpreter, or the module."""
    script = Path(sys.executable).parent / "hostd"
    if script.exists():
        return [str(script)]
    found = shutil.which("hostd")
    return [found] if found else [sys.executable, "-m", "hostd.app.cli"]


def ours_command(model: Path, out: Path, config: Path) -> list[str]:
    """The `hostd slice` command line with the benchmark settings."""
    cmd = [*hostd_executable(), "slice", str(model), "-o", str(out), "--quiet",
           "--config", str(config)]
    for setting in OUR_SETTINGS:
        cmd += ["--set", setting]
    return cmd


def stl_faces(path: Path) -> int:
    """Triangle count of an STL (binary header count, or ``facet`` lines if ASCII)."""
    data = path.read_bytes()
    if len(data) >= 84:
        count = int.from_bytes(data[80:84], "little")
        if 84 + 50 * count == len(data):
            return count
    return data.count(b"facet normal")


def model_paths(folder: Path, selected: str) -> list[Path]:
    """The .stl files of ``folder``, optionally only those named in ``selected`` (a,b,...)."""
    paths = sorted(folder.glob("*.stl"), key=lambda p: (p.stat().st_size, p.name))
    if not selected:
        return paths
    wanted = [s.strip().removesuffix(".stl") for s in selected.split(",") if s.strip()]
    chosen = [p for p in paths if p.stem in wanted]
    missing = sorted(set(wanted) - {p.stem for p in chosen})
    if missing:
        raise SystemExit(f"unknown models: {', '.join(missing)} (in {folder})")
    return chosen


def real_parts(shared: Path) -> list[Path]:
    """The CAD exports of printed parts in ``shared/real`` (read from there, never
    copied: GPL data); none when the folder is absent."""
    folder = shared / REAL
    return sorted(folder.glob("*.stl")) if folder.is_dir() else []


def corpus_paths(shared: Path, selected: str) -> list[Path]:
    """The shared models, the real parts (when their folder is there) and the generated
    corpus (written when missing), smallest first."""
    from bench.corpus import build

    paths = sorted([*shared.glob("*.stl"), *real_parts(shared), *build()],
                   key=lambda p: (p.stat().st_size, p.name))
    if not selected:
        return paths
    wanted = {s.strip().removesuffix(".stl") for s in selected.split(",") if s.strip()}
    missing = sorted(wanted - {p.stem for p in paths})
    if missing:
        raise SystemExit(f"unknown models: {', '.join(missing)}")
    return [p for p in paths if p.stem in wanted]


def large_case(args: argparse.Namespace, config: Path, gcode_dir: Path) -> int:
    """`hostd slice` of the 3.03M-triangle model: time, peak RSS against 2x the file + 100 MB."""
    from bench.corpus import large_model

    model = large_model()
    size_mb = model.stat().st_size / 1e6
    target = 2 * size_mb + 100
    out = gcode_dir / f"{model.stem}.hostd.gcode"
    for _ in range(args.repeat):
        result = run_measured(ours_command(model, out, config), timeout=args.timeout)
        rss = result.rss_mb or 0.0
        verdict = "ok" if result.ok and rss < target else "**over**"
        print(f"| {model.stem} | {stl_faces(model):,} | {size_mb:.1f} MB | {result.wall_s:.2f} s "
              f"| {rss:.0f} MB | {target:.0f} MB | {verdict} | {_clean(result.reason())} |")
    return 0


def make_scale_model(source: Path, rounds: int = 2) -> Path:
    """Subdivide every triangle of ``source`` into four, ``rounds`` times, into the cache."""
    import trimesh

    target = CACHE / f"{source.stem}_x{4 ** rounds}.stl"
    if target.exists():
        return target
    mesh = trimesh.load(source, force="mesh", process=False)
    vertices, faces = mesh.vertices, mesh.faces
    for _ in range(rounds):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    CACHE.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(vertices, faces, process=False).export(target)
    return target


def measure_model(
    model: Path, runners: list[Runner], repeat: int, timeout: float, config: Path,
    gcode_dir: Path, compare: bool = True,
) -> Row:
    """Slice ``model`` with every runner ``repeat`` times, alternating; parse the G-code."""
    runs: dict[str, list[RunResult]] = {r.name: [] for r in runners}
    cpus: dict[str, list[float]] = {r.name: [] for r in runners}
    outs = {r.name: gcode_dir / f"{model.stem}.{r.name}.gcode" for r in runners}
    for rep in range(repeat):
        order = runners[rep % len(runners):] + runners[:rep % len(runners)]
        for runner in order:
            outs[runner.name].unlink(missing_ok=True)
            before = _children_cpu()
            result = runner.run(model, outs[runner.name], timeout, config)
            cpu = _children_cpu() - before
            runs[runner.name].append(result)
            if result.ok:
                cpus[runner.name].append(cpu)
            print(f"  {model.stem:18s} {runner.name:12s} "
                  f"{'ok ' if result.ok else 'FAIL'} {result.wall_s:7.2f} s "
                  f"(CPU {cpu:6.2f} s) {result.rss_mb or 0:7.1f} MB {result.reason()}",
                  file=sys.stderr)
    row = Row(model=model.stem, faces=stl_faces(model), results={})
    moves: dict[str, gcodeparse.Moves] = {}
    for name, results in runs.items():
        row.results[name] = summarise(results)
        if cpus[name]:
            row.results[name].cpu_s = statistics.median(cpus[name])
        if row.results[name].ok and outs[name].exists():
            moves[name] = gcodeparse.read_moves(outs[name])
            st = gcodeparse.stats(moves[name])
            row.results[name].layers = st.layers
            row.results[name].filament_mm = st.filament_mm
    if compare:
        compare_walls(row, moves)
    return row


def _children_cpu() -> float:
    """CPU seconds (user + system) of every child process waited for so far: a run's
    is the difference around it (its own forked workers and threads included)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def cpu_table(rows: list[Row]) -> str:
    """Wall and CPU time of hostd against each peer, medians side by side: on a loaded
    machine the CPU time is disturbed less than the wall time, and CuraEngine's two
    threads turn CPU time into shorter wall time only where a core is free."""
    peers = [name for name in ("curaengine", "prusaslicer")
             if any(name in row.results for row in rows)]
    head = "| model | hostd wall, CPU |" + "".join(
        f" {name} wall, CPU | ours/{name} wall, CPU |" for name in peers)
    lines = [head, "|" + "---|" * (2 + 2 * len(peers))]
    for row in rows:
        ours = row.results.get("hostd")
        cells = [row.model, _times(ours)]
        for name in peers:
            peer = row.results.get(name)
            cpu = "-"
            if ours and peer and ours.cpu_s and peer.cpu_s:
                cpu = f"{ours.cpu_s / peer.cpu_s:.2f}"
            cells += [_times(peer), f"{_ratio(ours, peer)}, {cpu}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _times(m: Measured | None) -> str:
    if m is None or not m.ok:
        return "-"
    return f"{_fmt(m.wall_s, '.3f')} s, {_fmt(m.cpu_s, '.3f')} s"


def compare_walls(row: Row, moves: dict[str, gcodeparse.Moves]) -> None:
    """Fill the outer-wall IoU figures of ``row`` from the parsed G-code of each slicer."""
    ours, prusa, cura = moves.get("hostd"), moves.get("prusaslicer"), moves.get("curaengine")
    if ours is not None and prusa is not None:
        agreement = gcodeparse.wall_agreement(ours, prusa)
        row.iou_vs_prusa = agreement.mean_iou
        row.iou_vs_prusa_common = agreement.mean_iou_common
        row.worst_layers_vs_prusa = agreement.worst(8)
        row.offset_vs_prusa = agreement.offset
        worst = ", ".join(f"z={z:.1f}: {iou:.2f}" for z, iou in agreement.worst(4))
        print(f"  {row.model:18s} worst outer-wall layers vs PrusaSlicer: {worst}; "
              f"aligned by ({agreement.offset[0]:+.3f}, {agreement.offset[1]:+.3f}) mm",
              file=sys.stderr)
    if cura is not None and prusa is not None:
        row.iou_cura_vs_prusa = gcodeparse.wall_agreement(cura, prusa).mean_iou
    if ours is not None and cura is not None:
        row.iou_vs_cura = gcodeparse.wall_agreement(ours, cura).mean_iou


def summarise(results: list[RunResult]) -> Measured:
    """Medians of the successful runs; the failure reason when none succeeded."""
    good = [r for r in results if r.ok]
    if not good:
        return Measured(ok=False,
                        reason=_clean(results[-1].reason()) if results else "not run")
    rss = [r.rss_mb for r in good if r.rss_mb is not None]
    bad = [r for r in results if not r.ok]
    return Measured(
        ok=True,
        reason=_clean(f"{len(bad)} of {len(results)} runs failed: {bad[0].reason()}")
        if bad else "",
        wall_s=statistics.median(r.wall_s for r in good),
        peak_rss_mb=statistics.median(rss) if rss else None,
        runs=[round(r.wall_s, 3) for r in good],
    )


def _clean(text: str) -> str:
    """A failure reason without this machine's folders (paths shown relative to the repo)."""
    return text.replace(str(ROOT.parent) + "/", "../").replace(str(ROOT) + "/", "")


def _fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _ratio(a: Measured | None, b: Measured | None) -> str:
    if a is None or b is None or a.wall_s is None or b.wall_s is None or b.wall_s <= 0:
        return "-"
    return f"{a.wall_s / b.wall_s:.2f}"


def _filament_ratio(ours: Measured | None, peer: Measured | None) -> str:
    if ours is None or peer is None or not ours.filament_mm or not peer.filament_mm:
        return "-"
    return f"{ours.filament_mm / peer.filament_mm:.3f}"


def _cell(m: Measured | None) -> str:
    if m is None:
        return "-"
    if not m.ok:
        return "fails"
    return f"{_fmt(m.wall_s, '.2f')} s, {_fmt(m.peak_rss_mb, '.0f')} MB"


def table(rows: list[Row]) -> str:
    """The measured rows as a Markdown table."""
    head = ("| model | faces | hostd | PrusaSlicer | CuraEngine | ours/Prusa | ours/Cura "
            "| layers ours/P/C | filament ours/P, ours/C | wall IoU ours-P (common) | IoU ours-C "
            "| IoU Cura-P | note |")
    lines = [head, "|" + "---|" * 13]
    for row in rows:
        r = row.results
        ours, pr, cu = r.get("hostd"), r.get("prusaslicer"), r.get("curaengine")
        layers = "/".join(_fmt(m.layers if m else None, "d") for m in (ours, pr, cu))
        fil = "/".join(_filament_ratio(ours, peer) for peer in (pr, cu))
        iou = "-"
        if row.iou_vs_prusa is not None:
            iou = f"{row.iou_vs_prusa:.3f} ({_fmt(row.iou_vs_prusa_common, '.3f')})"
        notes = [f"{name}: {m.reason}" for name, m in r.items() if m.reason]
        lines.append(
            f"| {row.model} | {row.faces:,} | {_cell(ours)} | {_cell(pr)} | {_cell(cu)} "
            f"| {_ratio(ours, pr)} | {_ratio(ours, cu)} | {layers} | {fil} | {iou} "
            f"| {_fmt(row.iou_vs_cura, '.3f')} | {_fmt(row.iou_cura_vs_prusa, '.3f')} "
            f"| {'; '.join(notes)} |")
    return "\n".join(lines)


def scale_table(rows: list[Row]) -> str:
    """The scale case as a Markdown table."""
    lines = ["| model | faces | hostd | CuraEngine | ours/Cura | layers ours/C | note |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        r = row.results
        ours, cu = r.get("hostd"), r.get("curaengine")
        layers = "/".join(_fmt(m.layers if m else None, "d") for m in (ours, cu))
        notes = [f"{name}: {m.reason}" for name, m in r.items() if m.reason]
        lines.append(f"| {row.model} | {row.faces:,} | {_cell(ours)} | {_cell(cu)} "
                     f"| {_ratio(ours, cu)} | {layers} | {'; '.join(notes)} |")
    return "\n".join(lines)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="", help="comma-separated model names (default: all)")
    p.add_argument("--models-dir", type=Path, default=MODELS)
    p.add_argument("--repeat", type=int, default=1, help="runs per slicer (medians if > 1)")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per slicing run")
    p.add_argument("--peers", default="prusaslicer,curaengine")
    p.add_argument("--no-scale", action="store_true", help="skip the ~1M-face scale case")
    p.add_argument("--scale-only", action="store_true", help="only the scale case")
    p.add_argument("--out", type=Path, default=OUT, help="G-code and JSON results folder")
    p.add_argument("--large", action="store_true",
                   help="only the memory case: `hostd slice` of a 3.03M-triangle STL, peak RSS")
    p.add_argument("--corpus", action="store_true",
                   help="the shared models and the generated corpus, with the targets checked")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and print the tables."""
    args = parse_args(argv)
    write_bytecode()
    if not ensure_gnu_time():
        print("GNU time unavailable: peak RSS from getrusage", file=sys.stderr)
    peer_names = tuple(n.strip() for n in args.peers.split(",") if n.strip())
    runners = [Runner("hostd"), *(Runner(p.name, p) for p in available_peers(peer_names))]
    gcode_dir = args.out / "gcode"
    gcode_dir.mkdir(parents=True, exist_ok=True)
    config = args.out / "bench-printer.toml"
    config.write_text(BED_TOML)
    results: dict[str, object] = {"ours_settings": OUR_SETTINGS}
    if args.large:
        return large_case(args, config, gcode_dir)
    if args.corpus:
        before = machine_speed(sys.executable)
        print(speed_line(before), file=sys.stderr)
        rows = [measure_model(m, runners, args.repeat, args.timeout, config, gcode_dir,
                              compare=m.stem != "bad_triangle_soup")
                for m in corpus_paths(args.models_dir, args.models)]
        after = machine_speed(sys.executable)
        print(corpus_table.table(rows))
        print()
        print(cpu_table(rows))
        print(f"before: {speed_line(before)}\nafter:  {speed_line(after)}")
        results["corpus"] = [asdict(r) for r in rows]
        results["machine_before"], results["machine_after"] = before, after
        (args.out / "corpus_vs_peers.json").write_text(json.dumps(results, indent=1))
        return 0
    if not args.scale_only:
        rows = [measure_model(m, runners, args.repeat, args.timeout, config, gcode_dir,
                              compare=m.stem != "bad_triangle_soup")
                for m in model_paths(args.models_dir, args.models)]
        print(table(rows))
        print()
        print(cpu_table(rows))
        results["models"] = [asdict(r) for r in rows]
    if not args.no_scale:
        scale = make_scale_model(args.models_dir / SCALE_SOURCE)
        scale_runners = [r for r in runners if r.name in ("hostd", "curaengine")]
        row = measure_model(scale, scale_runners, args.repeat, args.timeout, config,
                            gcode_dir, compare=False)
        print()
        print(scale_table([row]))
        results["scale"] = asdict(row)
    (args.out / "slice_vs_peers.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
