"""The farm queue: N daemons on simulated printers taking M jobs from one JetStream queue.

A three-node nats-server cluster; N ``hostd run`` daemons with ``[farm]`` enabled,
on simulated printers at a high time scale, with two bed sizes (220x220 and
300x300) and two materials (PLA, PETG) in turn; M jobs of the tests' small models
(the 20 mm cube, the dogbone) with mixed needs (none, a material, a large bed, a
material and a large bed), submitted at once. Measured:

- every job printed exactly once: each job id in exactly one printer's ``done/``,
  and each printer's executed-line log equal to its done G-codes, in the order it
  took them (the printer killed mid-print: the same, around the part it printed
  of the job it held);
- the time from a printer turning idle (its job's ``done`` line) to the first
  extruding move of its next job (the runner's ``first extruding move
  acknowledged`` line), median and 95th percentile, over the printers' logs;
- with ``--faults``, the same run with one daemon that holds a job killed -9 and
  one NATS node stopped once a third of the jobs are printed; the killed daemon
  is started again, reports its job interrupted, and the job is given back with
  ``requeue`` (as the owner would): nothing printed twice, nothing lost.

``python -m bench.farm --daemons 4 --jobs 40 [--faults]``
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from support.brokers import HOST, NatsCluster, start_nats_cluster  # noqa: E402
from support.gcode_lines import commands_of, executed_job_lines  # noqa: E402

from hostd.config import FarmConfig  # noqa: E402
from hostd.farm.needs import parse_needs  # noqa: E402
from hostd.farm.queue import FarmQueue  # noqa: E402

MODELS = (ROOT / "tests" / "data" / "cube20_xyz.stl", ROOT / "tests" / "data" /
          "dogbone_100x30x5.stl")
NEEDS = ("", "material=PLA", "material=PETG", "bed=250x250", "material=PETG,bed=250x250")
ACK_WAIT_S = 3.0
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
STAMP = "%Y-%m-%d %H:%M:%S,%f"


@dataclass
class Printer:
    """One daemon on its simulated printer."""

    name: str
    material: str
    bed: int
    folder: Path
    proc: subprocess.Popen[bytes] | None = None
    runs: int = 0
    killed: list[str] = field(default_factory=list)  # farm jobs it held when killed

    @property
    def log(self) -> Path:
        return self.folder / "daemon.log"

    def start(self, servers: list[str], time_scale: float) -> None:
        urls = ", ".join(f'"{url}"' for url in servers)
        config = self.folder / "hostd.toml"
        config.write_text(
            f'[jobs]\nfolder = "{self.folder / "jobs"}"\nsettle_s = 0.2\n'
            f'[state]\nfolder = "{self.folder / "var"}"\n'
            f"[simulator]\ntime_scale = {time_scale}\nbaud = 0\n"
            f'[printer]\nid = "{self.name}"\nmaterial = "{self.material}"\n'
            f"bed = [{self.bed}, {self.bed}, 250]\n"
            f"[farm]\nenabled = true\nservers = [{urls}]\nack_wait_s = {ACK_WAIT_S}\n")
        self.runs += 1
        with open(self.log, "ab") as log:
            log.write(f"--- run {self.runs}\n".encode())
            log.flush()
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "hostd", "run", "--config", str(config)],
                stdout=log, stderr=subprocess.STDOUT, cwd=self.folder, env=ENV,
                start_new_session=True)

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def connected(self) -> bool:
        return self.text().count("farm: connected") >= self.runs

    def kill9(self) -> None:
        assert self.proc is not None
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()

    def stop(self) -> None:
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()

    def done(self) -> list[str]:
        """Farm job ids printed here, in the order taken (the local job number)."""
        found = []
        for summary in (self.folder / "jobs" / "done").glob("fj-*.summary.txt"):
            local = int(summary.read_text().split()[1])
            found.append((local, summary.name.split(".")[0]))
        return [job for _local, job in sorted(found)]


def wait(check: object, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if callable(check) and check():
            return
        time.sleep(0.2)
    raise RuntimeError(f"timed out waiting for {what}")


async def _queue(servers: list[str]) -> FarmQueue:
    return await FarmQueue.open(FarmConfig(servers=tuple(servers)), "hostd-farm-bench")


async def submit(servers: list[str], count: int) -> list[str]:
    """``count`` jobs, models and needs in turn."""
    queue = await _queue(servers)
    ids = []
    try:
        for index in range(count):
            model = MODELS[index % len(MODELS)]
            needs = parse_needs(NEEDS[index % len(NEEDS)])
            ids += await queue.submit(model.name, model.read_bytes(), 1, {}, needs)
    finally:
        await queue.close()
    return ids


async def states(servers: list[str]) -> dict[str, tuple[str, str | None, int]]:
    """Job id -> (state, printer, layer)."""
    queue = await _queue(servers)
    try:
        return {e.id: (e.state, e.printer, e.layer) for e, _r in await queue.entries()}
    finally:
        await queue.close()


async def requeue(servers: list[str], job_id: str) -> None:
    queue = await _queue(servers)
    try:
        await queue.requeue(job_id)
    finally:
        await queue.close()


def idle_to_extrusion(printer: Printer) -> list[float]:
    """Seconds from each job's ``done`` to the next job's first extruding move, per run."""
    gaps = []
    for run in printer.text().split("--- run ")[1:]:
        idle_at: datetime | None = None
        for line in run.splitlines():
            if ": done, G-code in " in line:
                idle_at = datetime.strptime(line[:23], STAMP)
            elif "first extruding move acknowledged" in line and idle_at is not None:
                gaps.append((datetime.strptime(line[:23], STAMP) - idle_at).total_seconds())
                idle_at = None
    return gaps


def check_once(printers: list[Printer], ids: list[str]) -> list[str]:
    """Problems found: a job printed twice or never, an executed log that differs."""
    problems = []
    where: dict[str, list[str]] = {}
    for printer in printers:
        for job in printer.done():
            where.setdefault(job, []).append(printer.name)
    for job in ids:
        if len(where.get(job, [])) != 1:
            problems.append(f"{job} printed by {where.get(job, [])}")
    for printer in printers:
        done_dir = printer.folder / "jobs" / "done"
        executed = executed_job_lines(printer.folder / "var" / "simulator-executed.log")
        pieces = [commands_of(done_dir / f"{job}.gcode") for job in printer.done()]
        expected = [line for piece in pieces for line in piece]
        if not printer.killed:
            if executed != expected:
                problems.append(f"{printer.name}: executed {len(executed)} lines, its done "
                                f"G-codes have {len(expected)}")
            continue
        # killed mid-print: its done jobs, with the part of the held job between them
        matched = 0
        position = 0
        for piece in pieces:
            found = _find(executed, piece, position)
            if found < 0:
                break
            matched += 1
            position = found + len(piece)
        if matched != len(pieces):
            problems.append(f"{printer.name}: {len(pieces) - matched} done jobs not found whole "
                            "in its executed log")
        elif len(executed) - len(expected) <= 0:
            problems.append(f"{printer.name}: nothing of the held job was executed")
    return problems


def _find(lines: list[str], piece: list[str], start: int) -> int:
    """Index of ``piece`` as a run of ``lines`` at or after ``start`` (-1: none)."""
    if not piece:
        return start
    first = piece[0]
    for index in range(start, len(lines) - len(piece) + 1):
        if lines[index] == first and lines[index:index + len(piece)] == piece:
            return index
    return -1


def run(daemons: int, jobs: int, time_scale: float, faults: bool) -> dict[str, object]:
    """One run; returns its figures."""
    tmp = Path(tempfile.mkdtemp(prefix="hostd-farm-bench-"))
    cluster: NatsCluster = start_nats_cluster(tmp / "nats")
    servers = [f"nats://{HOST}:{node.client_port}" for node in cluster.nodes]
    printers = []
    for index in range(daemons):
        folder = tmp / f"p{index + 1}"
        folder.mkdir()
        printers.append(Printer(f"p{index + 1}", ("PLA", "PETG")[index % 2],
                                (220, 300)[(index // 2) % 2], folder))
    try:
        for printer in printers:
            printer.start(servers, time_scale)
        wait(lambda: all(p.connected() for p in printers), 120, "the daemons")
        started = time.monotonic()
        ids = asyncio.run(submit(servers, jobs))
        submitted_s = time.monotonic() - started
        fault_note = ""
        if faults:
            wait(lambda: sum(s[0] == "printed" for s in asyncio.run(states(servers)).values())
                 >= jobs // 3, 600, "a third printed")
            found: dict[str, tuple[str, str | None, int]] = {}

            def holder_printing() -> bool:
                found.update(asyncio.run(states(servers)))
                return any(s[0] == "taken" and s[2] >= 0 for s in found.values())

            wait(holder_printing, 120, "a printer holding a job mid-print")
            job, (_state, holder, _layer) = next(
                (j, s) for j, s in found.items() if s[0] == "taken" and s[2] >= 0)
            victim = next(p for p in printers if p.name == holder)
            victim.kill9()
            victim.killed.append(job)
            cluster.nodes[0].stop()
            fault_note = f"killed {victim.name} holding {job}; stopped node n1"
            time.sleep(ACK_WAIT_S * 2)
            victim.start(servers[1:], time_scale)
            wait(lambda: asyncio.run(states(servers[1:]))[job][0] == "interrupted", 120,
                 "the held job reported interrupted")
            asyncio.run(requeue(servers[1:], job))
        alive = servers[1:] if faults else servers
        def finished() -> bool:
            now = asyncio.run(states(alive))
            return len(now) == len(ids) and all(s[0] in ("printed", "failed")
                                                for s in now.values())

        wait(finished, 1800, "every job")
        total_s = time.monotonic() - started
        final = asyncio.run(states(alive))
    finally:
        for printer in printers:
            printer.stop()
        cluster.stop()
    gaps = sorted(g for p in printers for g in idle_to_extrusion(p))
    problems = check_once(printers, ids)
    result: dict[str, object] = {
        "daemons": daemons, "jobs": jobs, "time_scale": time_scale, "faults": fault_note,
        "printed": sum(s[0] == "printed" for s in final.values()),
        "failed": sum(s[0] == "failed" for s in final.values()),
        "submit_s": round(submitted_s, 2), "total_s": round(total_s, 1),
        "idle_to_extrusion_median_s": round(statistics.median(gaps), 3) if gaps else None,
        "idle_to_extrusion_p95_s": round(gaps[int(0.95 * (len(gaps) - 1))], 3) if gaps else None,
        "gaps": len(gaps), "problems": problems,
    }
    shutil.rmtree(tmp, ignore_errors=True)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--daemons", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=40)
    parser.add_argument("--time-scale", type=float, default=0.002)
    parser.add_argument("--faults", action="store_true",
                        help="also the run with a daemon killed -9 and a node stopped")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    scenarios = [False, True] if args.faults else [False]
    bad = False
    for faults in scenarios:
        result = run(args.daemons, args.jobs, args.time_scale, faults)
        for key, value in result.items():
            print(f"{key}: {value}")
        print()
        bad = bad or bool(result["problems"]) or result["printed"] != args.jobs
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
