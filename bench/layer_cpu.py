"""CPU time per layer of `hostd slice`'s per-layer work, in one process: toolpaths, then G-code.

Wall-clock times of whole runs mean little on a loaded machine; the CPU time
of the process's own per-layer work, best of a few passes, is steadier. The
model is loaded and every outline and skin made first; repeated layers are not
reused, so every layer is sliced. Prints milliseconds per layer and a SHA-256
of the G-code, so two versions of the slicer can be compared on the same models
(run it with ``PYTHONPATH`` pointing at an exported tree of the other version).
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "bench" / ".cache" / "corpus"
SHARED = ROOT.parent / "shared" / "models"
# the peers' settings (bench/slice_vs_peers.py OUR_SETTINGS)
SETTINGS = {
    "layer_height": 0.2, "first_layer_height": 0.2, "line_width": 0.4, "perimeters": 2,
    "top_layers": 3, "bottom_layers": 3, "infill.field": "linear", "infill.density": 0.2,
    "support.enabled": False, "filament_diameter": 1.75, "skip_heating": True,
}


def model_path(name: str) -> Path:
    """The corpus model ``name`` (bench/corpus.py), else the shared one."""
    for folder in (CORPUS, SHARED):
        path = folder / f"{name}.stl"
        if path.exists():
            return path
    raise SystemExit(f"no model {name!r} in {CORPUS} or {SHARED} (run bench/corpus.py)")


def measure(name: str, passes: int) -> tuple[int, float, float, str]:
    """(layers, toolpaths ms/layer, toolpaths + G-code ms/layer, G-code digest) for a model."""
    from slicer.paths import islands
    from slicer.plan import SlicePlan
    from slicer.settings import SliceSettings

    settings = SliceSettings.from_mapping(SETTINGS)
    plan = SlicePlan.from_file(model_path(name), settings, bed=(200.0, 200.0, 200.0))
    plan.cut_all()
    n = plan.layer_count
    for i in range(n):
        plan._skins.get(i)
    plan._reuse = False  # every layer sliced, none taken from an equal one
    digest = hashlib.sha256()
    paths_s = code_s = float("inf")
    for k in range(passes):
        islands.forget()  # every pass offsets every island, as one slice does once
        start = time.process_time()
        for i in range(n):
            plan.layer_toolpaths(i)
        middle = time.process_time()
        for i in range(n):
            lines = plan.layer_gcode(i)
            if k == 0:
                digest.update("\n".join(lines).encode())
        end = time.process_time()
        paths_s, code_s = min(paths_s, middle - start), min(code_s, end - middle)
    return n, 1000 * paths_s / max(n, 1), 1000 * code_s / max(n, 1), digest.hexdigest()[:16]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+", help="corpus or shared model names")
    p.add_argument("--passes", type=int, default=3, help="passes per model (best is kept)")
    args = p.parse_args(argv)
    print("| model | layers | toolpaths ms/layer | toolpaths + G-code ms/layer | G-code sha256 |")
    print("|---|---|---|---|---|")
    for name in args.models:
        n, paths_ms, code_ms, digest = measure(name, args.passes)
        print(f"| {name} | {n} | {paths_ms:.2f} | {code_ms:.2f} | {digest} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
