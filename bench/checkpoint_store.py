"""Streaming rate of a job with a job store whose commits take no time, and 200 ms each.

The runner prints the dogbone (sliced just in time, as in the daemon) to the
simulated printer on a 250000-baud wire with moves taking no time, so the wire
and the host are the limits; every acknowledgement hands a checkpoint to the
checkpoint writer, which commits it in its own thread. The store either
commits as SQLite does here, or sleeps ``--delay-ms`` (a slow SD card's fsync)
before every commit. The two alternate ``--repeat`` times; the table gives the
median job lines per second (first line sent to last acknowledged), the
resends, errors and probes (sent when an `ok` is late), and the commits made: the slow store makes
fewer (a checkpoint replaces one not yet written), the printer's lines do not
wait for them.

Usage (from the repository root):
    .venv/bin/python bench/checkpoint_store.py [--repeat 3] [--delay-ms 200]
"""

from __future__ import annotations

import argparse
import asyncio
import concurrent.futures
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from drivers.link.streamer import Streamer, StreamerConfig  # noqa: E402
from drivers.link.transport import open_transport  # noqa: E402
from drivers.sim.config import SimulatorConfig  # noqa: E402
from drivers.sim.printer import SimulatedPrinter  # noqa: E402
from hostd.jobs.joblife import JobLife  # noqa: E402
from hostd.jobs.jobstore import JobStore  # noqa: E402
from hostd.jobs.schedule import LayerSchedule  # noqa: E402
from hostd.printing.runner import JobRunner, open_output  # noqa: E402
from hostd.printing.sources import SlicedSource  # noqa: E402
from hostd.publishing.status import StatusHub  # noqa: E402
from slicer.plan import SlicePlan  # noqa: E402
from slicer.settings import SliceSettings  # noqa: E402

MODEL = ROOT / "tests" / "data" / "dogbone_100x30x5.stl"
BAUD = 250000


class SlowStore(JobStore):
    """A job store whose every commit first sleeps ``delay_s`` (its reopened connections too)."""

    def __init__(self, path: Path, delay_s: float = 0.0) -> None:
        self.delay_s = delay_s
        super().__init__(path)

    def _commit(self) -> None:
        if self.delay_s:
            time.sleep(self.delay_s)
        super()._commit()

    def reopen(self, durable: bool = True) -> SlowStore:
        store = SlowStore(self.path, self.delay_s)
        if not durable:
            store.relax()
        return store


@dataclass(frozen=True)
class Run:
    """One print: job lines, seconds from the first sent to the last acknowledged, link
    counters and checkpoints committed."""

    lines: int
    seconds: float
    resends: int
    errors: int
    probes: int
    commits: int

    @property
    def rate(self) -> float:
        return self.lines / self.seconds


async def print_once(plan: SlicePlan, settings: SliceSettings, folder: Path, delay_s: float
                     ) -> Run:
    """Print the plan once on a fresh simulated printer and store in ``folder``."""
    store = SlowStore(folder / "jobs.sqlite3", delay_s)
    job = store.add("dogbone.stl", str(MODEL), str(MODEL), "stl", "00", settings.to_mapping())
    store.transition(job.id, "slicing")
    printer = SimulatedPrinter(SimulatorConfig(time_scale=0.0, baud=BAUD))
    path = printer.start()
    executor = concurrent.futures.ThreadPoolExecutor(2)
    try:
        async with Streamer(await open_transport(path, BAUD), StreamerConfig()) as link:
            await link.connect()
            source = SlicedSource(LayerSchedule(plan, settings), 0, 3, executor, resume=False)
            output = open_output(folder / "out.gcode.part", 0)
            runner = JobRunner(job, source, link, JobLife(store, StatusHub()), output, 0,
                               write_preamble=True)
            acked: list[float] = []
            on_ack = runner.on_ack

            def timed(ack) -> None:
                acked.append(time.perf_counter())
                on_ack(ack)

            runner.on_ack = timed  # type: ignore[method-assign]
            started = time.perf_counter()
            await runner.run()
            output.close()
            stats = link.stats
            commits = runner.writer.commits if runner.writer else 0
    finally:
        executor.shutdown()
        printer.stop()
        store.close()
    return Run(len(acked), acked[-1] - started, stats.resends, stats.errors, stats.probes,
               commits)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3, help="prints with each store")
    p.add_argument("--delay-ms", type=float, default=200.0, help="the slow store's commit delay")
    args = p.parse_args(argv)
    settings = SliceSettings()
    plan = SlicePlan.from_file(MODEL, settings)
    runs: dict[float, list[Run]] = {0.0: [], args.delay_ms / 1000: []}
    with tempfile.TemporaryDirectory(prefix="checkpoint-store-") as tmp:
        for k in range(args.repeat):
            for delay in runs:
                folder = Path(tmp) / f"{k}-{delay}"
                folder.mkdir()
                runs[delay].append(asyncio.run(print_once(plan, settings, folder, delay)))
    print(f"dogbone, {BAUD} baud, moves taking no time; median of {args.repeat} prints each")
    print("| store commit | job lines | lines/s | resends | errors | probes (lost `ok`s) "
          "| commits |")
    print("|---|---|---|---|---|---|---|")
    for delay, done in runs.items():
        print(f"| {delay * 1000:.0f} ms | {done[0].lines} | "
              f"{statistics.median(r.rate for r in done):,.0f} | "
              f"{max(r.resends for r in done)} | {max(r.errors for r in done)} | "
              f"{max(r.probes for r in done)} | {statistics.median(r.commits for r in done):.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
