"""Moves laid twice by resuming after kill -9: where the printer stopped vs. where the layer began.

One print of the dogbone on the simulated printer (time scale 0.004) is killed with
SIGKILL at ``--kills`` random instants, each time restarted and resumed with
`hostd resume`, until it is done. For every resume it counts the extruding moves
(G0/G1 with X or Y and E > 0) the simulated printer carried out twice: from where
the resume joined the job to the last move the killed run carried out. Next to it,
what a resume from the start of the interrupted layer (the former behaviour) would
have repeated. The simulated printer runs in the daemon's process, so each kill is
also a printer reset: the resume goes back the planner's 16 moves.

Usage (from the repository root):
    .venv/bin/python bench/resume_repeats.py [--kills 12] [--seed 7]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.link.protocol import strip_comment  # noqa: E402
from slicer.plan import SlicePlan  # noqa: E402
from slicer.settings import SliceSettings  # noqa: E402

MODEL = ROOT / "tests" / "data" / "dogbone_100x30x5.stl"
HOSTD = [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]
HOUSEKEEPING = ("M110", "M105", "M115", "M155")
REPLAY = 16  # [runner] replay_lines, the default


def extruding(command: str) -> bool:
    words = command.split()
    if words[0] not in ("G0", "G1") or not any(w[0] in "XY" for w in words[1:]):
        return False
    return any(w[0] == "E" and float(w[1:]) > 0 for w in words[1:])


def row(state: Path) -> tuple[str, int, int]:
    if not (state / "jobs.sqlite3").exists():
        return ("", -1, 0)
    db = sqlite3.connect(state / "jobs.sqlite3")
    try:
        found = db.execute("SELECT state, layer, layer_lines FROM jobs WHERE seq = 1").fetchone()
    except sqlite3.Error:
        found = None
    finally:
        db.close()
    return tuple(found) if found else ("", -1, 0)


def wait(check, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        if time.monotonic() > deadline:
            raise SystemExit("timed out")
        time.sleep(0.05)


def executed(log: Path, offset: int) -> list[str]:
    with open(log, encoding="utf-8") as handle:
        handle.seek(offset)
        lines = [line.rstrip("\n") for line in handle]
    return [c for c in lines if c and c.split()[0] not in HOUSEKEEPING]


def joined(run: list[str], reference: list[str], start: int) -> int:
    """How many job commands from ``start`` on the run carried out (after its resume block)."""
    for before in range(min(len(run), 40) + 1):
        rest = run[before:]
        if rest and rest == reference[start:start + len(rest)]:
            return len(rest)
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=12)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    plan = SlicePlan.from_file(MODEL, SliceSettings())
    reference = [c for c in map(strip_comment, plan.start_gcode()) if c]
    layer_start = []
    for index in range(plan.layer_count):
        layer_start.append(len(reference))
        reference += [c for c in map(strip_comment, plan.layer_gcode(index)) if c]
    reference += [c for c in map(strip_comment, plan.end_gcode()) if c]

    folder = Path(tempfile.mkdtemp(prefix="hostd-resume-"))
    state, jobs = folder / "var", folder / "jobs"
    config = folder / "hostd.toml"
    config.write_text("[jobs]\nsettle_s = 0.2\n[simulator]\ntime_scale = 0.004\nbaud = 0\n")
    sim_log = state / "simulator-executed.log"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    log = open(folder / "daemon.log", "ab")  # noqa: SIM115

    def start() -> subprocess.Popen[bytes]:
        return subprocess.Popen([*HOSTD, "run", "--config", str(config)], cwd=folder,
                                stdout=log, stderr=log, env=env)

    proc = start()
    jobs.mkdir(parents=True, exist_ok=True)
    (jobs / ".d.part").write_bytes(MODEL.read_bytes())
    os.replace(jobs / ".d.part", jobs / "dogbone.stl")
    start_at, offset = 0, 0
    ours, layer_start_resume = [], []
    for _kill in range(args.kills):
        wait(lambda: row(state)[0] == "printing", 60)
        time.sleep(rng.uniform(0.2, 1.5))
        if row(state)[0] != "printing":
            break
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        _state, layer, layer_lines = row(state)
        run = executed(sim_log, offset)
        offset = sim_log.stat().st_size
        end = start_at + joined(run, reference, start_at)
        first = layer + 1
        if first >= plan.layer_count:
            break
        start_at = max(layer_start[first], layer_start[first] + layer_lines - REPLAY)
        ours.append(sum(map(extruding, reference[start_at:end])))
        layer_start_resume.append(sum(map(extruding, reference[layer_start[first]:end])))
        connected = (folder / "daemon.log").read_bytes().count(b"printer connected")
        proc = start()
        wait(lambda c=connected: (folder / "daemon.log").read_bytes().count(
            b"printer connected") > c, 30)
        subprocess.run([*HOSTD, "resume", "1", "--config", str(config)], cwd=folder, env=env,
                       capture_output=True, timeout=30, check=True)
    wait(lambda: row(state)[0] == "done", 300)
    proc.send_signal(signal.SIGINT)
    proc.wait(30)
    print(f"{len(ours)} resumes after kill -9 (dogbone, {plan.layer_count} layers)")
    print(f"extruding moves laid twice, resuming where the printer stopped: {ours}")
    print(f"  total {sum(ours)}, most in one resume {max(ours, default=0)}")
    print(f"the same resumes from the start of the layer would have laid twice: "
          f"{layer_start_resume}")
    print(f"  total {sum(layer_start_resume)}, most in one resume "
          f"{max(layer_start_resume, default=0)}")
    print("firmware buffers: 4 commands (BUFSIZE) + 16 planner blocks = 20")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
