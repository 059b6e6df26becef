"""Memory: a print's objects go with it, and what the daemon keeps does not grow with jobs.

The daemon runs in this process (its event loop, slicing threads and the
simulated printer at full speed), so the test can look at what it holds after
each job: weak references to the job's objects, and the Python memory traced
across identical jobs.
"""

from __future__ import annotations

import asyncio
import gc
import itertools
import os
import shutil
import tracemalloc
import weakref
from pathlib import Path

import trimesh
from support.daemon_process import sim_config
from support.waiting import until

from hostd.app.daemon import Daemon
from hostd.config import load_config

# Python memory a whole job may leave behind (the status snapshot, history rows, the log
# records the test's capture keeps: 0-15 kB measured); the box below prints some 800
# commands, and a copy of each, kept anywhere (the simulated printer's list of executed
# commands did), took 80-95 kB a job
LEFT_PER_JOB_BYTES = 40_000
# the link keeps the last lines sent for resends (bounded): few, so that they are all
# another job's after the first one
LINK = "[printer.link]\nhistory = 256\n"


def box(path: Path) -> Path:
    """A 12 x 12 x 4 mm box: 20 layers, a few seconds at full speed."""
    trimesh.creation.box((12.0, 12.0, 4.0)).export(path)
    return path


def drop(model: Path, jobs: Path) -> None:
    """Put ``model`` into the job folder whole (a hidden copy, then a rename)."""
    hidden = jobs / f".{model.name}.part"
    shutil.copyfile(model, hidden)
    os.replace(hidden, jobs / model.name)


def ended(jobs: Path) -> int:
    """Jobs done so far."""
    return len(list((jobs / "done").glob("*.summary.txt")))


async def print_one(daemon: Daemon, model: Path, jobs: Path) -> dict[str, weakref.ref[object]]:
    """Print ``model`` to the end; weak references to what its print owned."""
    before = ended(jobs)
    drop(model, jobs)
    job = await until(lambda: daemon.current if daemon.current is not None
                      and daemon.current.runner is not None else None, 60, "the job printing")
    assert job.schedule is not None
    assert job.source is not None
    owned: dict[str, object] = {
        "active job": job, "runner": job.runner, "source": job.source, "schedule": job.schedule,
        "plan": job.schedule.base_plan, "eta": job.runner.eta,
    }
    refs = {name: weakref.ref(thing) for name, thing in owned.items()}
    del job, owned
    await until(lambda: ended(jobs) > before and daemon.current is None, 120, "the job done")
    await asyncio.sleep(0.3)  # the job's threads (checkpoint writer, estimates) let go
    return refs


def test_a_finished_print_releases_what_it_owned_and_keeps_no_line_it_printed(tmp_path):
    config = tmp_path / "hostd.toml"
    config.write_text(sim_config(time_scale=0.0, settle_s=0.1, extra=LINK))
    model = box(tmp_path / "box.stl")

    async def scenario() -> tuple[dict[str, weakref.ref[object]], list[int]]:
        daemon = Daemon(load_config(config, cwd=tmp_path))
        jobs = daemon.config.jobs.folder
        running = asyncio.create_task(daemon.run())
        try:
            await until(lambda: daemon.link is not None, 30, "the printer connected")
            await print_one(daemon, model, jobs)  # first uses: modules, caches, threads
            traced: list[int] = []
            tracemalloc.start()
            try:
                for _ in range(3):
                    refs = await print_one(daemon, model, jobs)
                    gc.collect()
                    traced.append(tracemalloc.get_traced_memory()[0])
            finally:
                tracemalloc.stop()
            return refs, traced
        finally:
            daemon._stop.set()
            await running

    refs, traced = asyncio.run(scenario())
    alive = sorted(name for name, ref in refs.items() if ref() is not None)
    assert alive == [], f"still held after the print ended: {alive}"
    # jobs 3 and 4 leave no more behind than job 2 did, whatever they printed
    growth = [later - earlier for earlier, later in itertools.pairwise(traced)]
    assert all(g < LEFT_PER_JOB_BYTES for g in growth), (traced, growth)
