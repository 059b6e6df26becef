"""Seeded loop over the core's interleaving test: random cuts and reply delays per seed.

The hypothesis test in ``tests/unit/test_drivers_core.py`` draws 40 new cases per run; this
runs thousands the same way (each write cut in up to 3 places, each reply delayed by one
of the test's delays, 8 % of every fault kind with resets and of the firmware dialect's
own fault, 120 lines, both ``ok`` dialects, every firmware dialect of
``drivers.sim.config.DIALECTS``), seeded, so a failure is replayed by its seed and
dialect. Prints one line per run that ran a line twice as a boot fragment (``FRAG``)
or failed (``FAIL``), then the figures, with the printer's receive-buffer overruns
(bytes lost past its 128 bytes: noise and resets cause none, only a host that writes
more than the buffer holds).

    .venv/bin/python -m bench.interleavings --seeds 0 1500 [--dialects marlin next_line]
"""

from __future__ import annotations

import argparse
import itertools
import random
import sys
import time
from pathlib import Path

from drivers.link.config import StreamerConfig
from drivers.sim.config import DIALECTS, SimulatorConfig
from drivers.sim.virtual import VirtualPrinter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # support
from support.linkrun import NoConvergence, run_core

from tests.unit.test_drivers_core import (
    LINK,
    NO_OK_LINK,
    _once_but_boot_fragments,
    dialect_faults,
    spiral,
    wire,
)

DELAYS = (0.0, 0.0, 0.0002, 0.001, 0.004)


def one_run(seed: int, ok_after_resend: bool, lines: list[str],
            name: str = "marlin") -> tuple[str, int]:
    """``"ok"``, ``"frag"`` (exactly once but a boot fragment) or ``"fail"``, and the
    bytes the printer's receive buffer lost to overruns."""
    rng = random.Random(seed * 2 + ok_after_resend)
    sim: SimulatorConfig = wire(seed=seed, ok_after_resend=ok_after_resend,
                                **dialect_faults(name, 0.08))

    def split(chunk: bytes) -> list[bytes]:
        count = rng.randint(0, 3) if len(chunk) > 1 else 0
        cuts = sorted(rng.randint(1, len(chunk) - 1) for _ in range(count))
        edges = [0, *cuts, len(chunk)]
        return [chunk[a:b] for a, b in itertools.pairwise(edges) if b > a]

    printers: list[VirtualPrinter] = []

    def hook(printer: VirtualPrinter) -> None:
        printers.append(printer)
        printer.split = split
        printer.to_host.delay = lambda _size: rng.choice(DELAYS)

    link: StreamerConfig = LINK if ok_after_resend else NO_OK_LINK
    try:
        run = run_core(lines, sim, link, printer_hook=hook, max_seconds=600)
    except (NoConvergence, RuntimeError):
        return "fail", printers[0].overrun_bytes if printers else 0
    overrun = run.printer.overrun_bytes
    if run.acked != lines or _once_but_boot_fragments(
            run.executed, run.printer.unnumbered, lines) != lines:
        return "fail", overrun
    return ("ok" if run.executed == lines else "frag"), overrun


def main() -> None:
    """Run the seeds given; print failures, boot fragments and the totals."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs=2, type=int, default=(0, 500), metavar=("FROM", "TO"))
    parser.add_argument("--dialects", nargs="+", default=sorted(DIALECTS),
                        choices=sorted(DIALECTS), help="firmware dialects (default: all)")
    args = parser.parse_args()
    lines = spiral(120)
    counts = {"ok": 0, "frag": 0, "fail": 0}
    overrun_runs = overrun_bytes = 0
    start = time.process_time()
    failed: dict[str, int] = {}
    for name in args.dialects:
        for seed in range(*args.seeds):
            for ok_after_resend in (True, False):
                outcome, overrun = one_run(seed, ok_after_resend, lines, name)
                counts[outcome] += 1
                failed[name] = failed.get(name, 0) + (outcome == "fail")
                if overrun:
                    overrun_runs += 1
                    overrun_bytes += overrun
                if outcome != "ok" or overrun:
                    print(f"{outcome.upper()} dialect={name} seed={seed} "
                          f"ok_after_resend={ok_after_resend}"
                          f"{f' overrun={overrun} bytes' if overrun else ''}", flush=True)
    runs = sum(counts.values())
    print(f"{runs} runs: {counts['fail']} failed, {counts['frag']} boot fragments, "
          f"{overrun_runs} with receive-buffer overruns ({overrun_bytes} bytes lost), "
          f"{time.process_time() - start:.0f} s of CPU")
    print("failed by dialect: " + ", ".join(f"{k} {v}" for k, v in failed.items()))


if __name__ == "__main__":
    main()
