"""kill -9 during a print: every restart reports the job, `hostd resume` finishes it identically."""

from __future__ import annotations

import asyncio
import random
import sqlite3
import subprocess
import time
from pathlib import Path

from support.daemon_process import sim_config
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA, HOSTD, ROOT

from drivers.link.protocol import strip_comment
from hostd.api import ControlClient
from slicer.paths.arcs import for_printer
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

MODEL = DATA / "dogbone_100x30x5.stl"


def job_row(state: Path) -> tuple[str, int]:
    """(state, last completed layer) of job 1, read straight from the job store."""
    return checkpoint_row(state)[:2]


def checkpoint_row(state: Path) -> tuple[str, int, int]:
    """(state, last completed layer, commands of the next layer acknowledged) of job 1."""
    db = sqlite3.connect(state / "jobs.sqlite3")
    try:
        row = db.execute("SELECT state, layer, layer_lines FROM jobs WHERE seq = 1").fetchone()
    finally:
        db.close()
    return (row[0], row[1], row[2]) if row else ("", -1, 0)


def extruding(command: str) -> bool:
    """A move that lays plastic: G0/G1 with X or Y and E > 0."""
    words = command.split()
    if words[0] not in ("G0", "G1") or not any(w[0] in "XY" for w in words[1:]):
        return False
    return any(w[0] == "E" and float(w[1:]) > 0 for w in words[1:])


def job_part(executed: list[str], reference: list[str], start: int) -> tuple[int, int]:
    """Where a run's executed lines join the job at ``start``: (lines before, job lines).

    A run carries out its resume block and the moves back (nothing when it starts
    at 0), then the job's commands from ``start`` on, until it is killed.
    """
    for before in range(min(len(executed), 40) + 1):
        rest = executed[before:]
        if rest and rest == reference[start:start + len(rest)]:
            return before, len(rest)
    return len(executed), 0  # killed before the first command of the job


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

    settings = for_printer(SliceSettings(), {"ARCS"})  # the simulator reports ARCS
    plan = SlicePlan.from_file(MODEL, settings)
    reference = [c for c in map(strip_comment, plan.start_gcode()) if c]
    layers = []
    layer_start = []
    for index in range(plan.layer_count):
        layer_start.append(len(reference))
        layers.append([c for c in map(strip_comment, plan.layer_gcode(index)) if c])
        reference += layers[-1]
    ending = [c for c in map(strip_comment, plan.end_gcode()) if c]
    reference += ending

    last_layer = -1
    log_start = 0
    starts = [0]  # where each run joins the job (an index into `reference`)
    recorded = []  # where the job store said the printer was at each kill
    runs: list[list[str]] = []
    for _attempt in range(3):
        hostd.wait_for(lambda: job_row(hostd.state)[0] == "printing", 30, "printing")
        time.sleep(rng.uniform(0.3, 2.0))  # the kill instant, at random
        if job_row(hostd.state)[0] != "printing":
            break
        hostd.kill9()
        state, layer, layer_lines = checkpoint_row(hostd.state)
        assert state == "printing"
        assert layer >= last_layer
        runs.append(executed_job_lines_from(executed_log, log_start))
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
        # the message counts layers from 1
        assert f"at layer {layer + 2 if layer >= 0 or layer_lines else 1}" in result.stdout
        # the simulated printer lived in the killed process: it lost its buffers, so the
        # resume goes back what its planner held (replay_lines, 16 moves), no further
        if layer + 1 < plan.layer_count and (layer >= 0 or layer_lines):
            recorded.append(layer_start[layer + 1] + layer_lines)
            starts.append(max(layer_start[layer + 1], recorded[-1] - 16))
        else:
            recorded.append(0 if layer < 0 else layer_start[-1] + len(layers[-1]))
            starts.append(recorded[-1])
        last_layer = layer
    assert len(runs) >= 2
    done = hostd.jobs / "done"
    hostd.wait_for(lambda: (done / "dogbone.summary.txt").exists(), 60, "the resumed job done")
    assert hostd.stop() == 0
    runs.append(executed_job_lines_from(executed_log, log_start))

    # the G-code file of the job is the uninterrupted print's, line for line
    assert commands_of(done / "dogbone.gcode") == reference

    # each run carried out its resume block and at most a few moves back (lifted: no
    # extrusion), then the job from where it joined; no command was ever left out; the
    # resume itself goes back no more than the planner held (16 moves), and what was laid
    # twice besides is what the printer did after the last checkpoint was committed
    repeated = []
    gone_back = []
    for number, (executed, start) in enumerate(zip(runs, starts, strict=True)):
        before, count = job_part(executed, reference, start)
        if number:
            preamble = [c for c in map(strip_comment, plan.resume_gcode(
                min(last_layer + 1, plan.layer_count - 1))) if c]
            moves_back = executed[len(preamble):before] if before >= len(preamble) else []
            assert len(moves_back) <= 4
            assert not any(map(extruding, moves_back))
        if number + 1 < len(runs):
            end = start + count
            following = starts[number + 1]
            assert following <= end, "a command never carried out was skipped"
            assert recorded[number] <= end, "the checkpoint ran ahead of the printer"
            repeated.append(sum(map(extruding, reference[following:end])))
            gone_back.append(sum(map(extruding, reference[following:recorded[number]])))
        else:
            assert start + count == len(reference)  # the last run finished the job
    report = (f"extruding moves carried out twice per resume: {repeated} "
              f"(of which the resume went back over: {gone_back})")
    assert all(count <= 16 for count in gone_back), report


def executed_job_lines_from(log: Path, offset: int) -> list[str]:
    """The job lines the simulated printer carried out from byte ``offset`` of its log on."""
    with open(log, encoding="utf-8") as handle:
        handle.seek(offset)
        text = handle.read()
    part = log.with_name(f"run-{offset}.log")
    part.write_text(text)
    return executed_job_lines(part)
