"""kill -9 during a print: every restart reports the job, `hostd resume` finishes it identically."""

from __future__ import annotations

import asyncio
import random
import sqlite3
import subprocess
import time
from pathlib import Path

from conftest import DATA, HOSTD, ROOT, commands_of, executed_job_lines, sim_config

from drivers.protocol import strip_comment
from hostd.api import ControlClient
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

MODEL = DATA / "dogbone_100x30x5.stl"


def job_row(state: Path) -> tuple[str, int]:
    """(state, last completed layer) of job 1, read straight from the job store."""
    db = sqlite3.connect(state / "jobs.sqlite3")
    try:
        row = db.execute("SELECT state, layer FROM jobs WHERE seq = 1").fetchone()
    finally:
        db.close()
    return (row[0], row[1]) if row else ("", -1)


def reported_interrupted(socket: Path) -> list[tuple[str, str, int]]:
    async def ask() -> list[tuple[str, str, int]]:
        async with ControlClient(str(socket)) as client:
            status = await client.status()
        return [(item.id, item.name, item.layer) for item in status.interrupted]

    return asyncio.run(ask())


def resume(config: Path, job: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*HOSTD, "resume", job, "--config", str(config)],
        capture_output=True, text=True, cwd=config.parent, timeout=30,
        env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )


def test_kill_9_at_random_instants_then_resume_reproduces_the_print(daemon) -> None:
    rng = random.Random(20261121)
    hostd = daemon(sim_config(time_scale=0.004, extra="[runner]\nlookahead = 3\n"))
    executed_log = hostd.state / "simulator-executed.log"
    hostd.drop(MODEL, "dogbone.stl")
    last_layer = -1
    kills = 0
    log_start = 0
    for _attempt in range(3):
        hostd.wait_for(lambda: job_row(hostd.state)[0] == "printing", 30, "printing")
        time.sleep(rng.uniform(0.3, 2.0))
        if job_row(hostd.state)[0] != "printing":
            break
        hostd.kill9()
        kills += 1
        state, layer = job_row(hostd.state)
        assert state == "printing" and layer >= last_layer
        log_start = executed_log.stat().st_size
        hostd.start()
        assert job_row(hostd.state) == ("interrupted", layer)
        socket = hostd.state / "hostd.sock"
        hostd.wait_for(socket.exists, 10, "the control socket")
        assert reported_interrupted(socket) == [("1", "dogbone.stl", layer)]
        assert f"interrupted after layer {layer}" in hostd.run_log()
        # nothing else runs while the part is on the bed, until resumed
        result = resume(hostd.config, "1")
        assert result.returncode == 0, result.stdout + result.stderr
        assert f"at layer {layer + 2 if layer >= 0 else 1}" in result.stdout  # counted from 1
        last_layer = layer
    assert kills >= 2
    done = hostd.jobs / "done"
    hostd.wait_for(lambda: (done / "dogbone.summary.txt").exists(), 60, "the resumed job done")
    assert hostd.stop() == 0

    settings = SliceSettings()
    plan = SlicePlan.from_file(MODEL, settings)
    reference = [c for c in map(strip_comment, plan.start_gcode()) if c]
    layers = []
    for index in range(plan.layer_count):
        layers.append([c for c in map(strip_comment, plan.layer_gcode(index)) if c])
        reference += layers[-1]
    ending = [c for c in map(strip_comment, plan.end_gcode()) if c]
    reference += ending
    # the G-code file of the job is the uninterrupted print's, line for line
    assert commands_of(done / "dogbone.gcode") == reference

    # the last run executed the resume preamble, then exactly the original from that layer on
    with open(executed_log, encoding="utf-8") as handle:
        handle.seek(log_start)
        tail = Path(hostd.folder / "tail.log")
        tail.write_text(handle.read())
    executed = executed_job_lines(tail)
    first = last_layer + 1
    if first == 0:
        expected = reference
    elif first == plan.layer_count:  # killed after the last layer: only the ending was left
        expected = ending
    else:
        preamble = [c for c in map(strip_comment, plan.resume_gcode(first)) if c]
        expected = preamble + [c for layer in layers[first:] for c in layer] + ending
    assert executed == expected
