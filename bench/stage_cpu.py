"""CPU seconds per stage of `hostd slice --profile`, best of a few runs in one process.

`--profile` times the stages by the wall clock, which a loaded machine makes
mean little; here the same stage timers read the process's CPU time instead.
The first run of each model only warms the imports (its figures are not
kept); each run after it starts with no island kept (:mod:`slicer.paths.islands`),
as a new process does. Compare two versions of the slicer by running this with
``PYTHONPATH`` pointing at an exported tree of the other version.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time

from bench.layer_cpu import model_path

STAGES = ("outlines", "skins", "walls", "infill", "ordering", "G-code", "other", "total")


class _CpuClock:
    """Stands in for the ``time`` module of the stage timers: CPU time, not wall time."""

    perf_counter = staticmethod(time.process_time)
    monotonic = staticmethod(time.process_time)


def run_once(name: str, out: str) -> dict[str, float]:
    """CPU seconds per stage (:data:`STAGES`) of one `hostd slice --profile` of ``name``."""
    import hostd.app.commands.slice as slice_cmd
    import hostd.app.commands.slice_profile as slice_profile
    from hostd.app import cli

    try:
        from slicer.paths import islands

        islands.forget()
    except ImportError:  # a version without the island cache
        pass
    slice_profile.time = _CpuClock  # type: ignore[assignment]
    slice_cmd.time = _CpuClock  # type: ignore[assignment]
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        cli.main(["slice", "--quiet", "--profile", "-o", out, str(model_path(name))])
    seconds = {}
    for line in text.getvalue().splitlines():
        for stage in STAGES:
            if line.startswith(stage):
                seconds[stage] = float(line[32:].split()[0])
    return seconds


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("models", nargs="+", help="corpus or shared model names")
    p.add_argument("--runs", type=int, default=3, help="measured runs per model (best is kept)")
    p.add_argument("--out", default="/dev/null", help="where the G-code goes")
    args = p.parse_args(argv)
    print("| model | " + " | ".join(STAGES) + " |")
    print("|---" * (len(STAGES) + 1) + "|")
    for name in args.models:
        run_once(name, args.out)  # imports warmed
        best: dict[str, float] = {}
        for _ in range(args.runs):
            for stage, s in run_once(name, args.out).items():
                best[stage] = min(best.get(stage, float("inf")), s)
        cells = " | ".join(f"{best.get(stage, 0.0):.3f}" for stage in STAGES)
        print(f"| {name} | {cells} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
