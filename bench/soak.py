"""Soak: many prints back to back on one daemon, its resident memory after each.

A `hostd run` daemon with the default configuration on the simulated printer at
full speed (``time_scale = 0``, the simulator's default 250000 baud unless
``--baud``) prints a mix of the shared models one after the other. Some jobs are
cancelled while they print (every ``--cancel-every``-th), one is retuned mid-print
(``set infill.density``), the others run to the end. After each job has ended and
the daemon is idle, the daemon's RSS (``VmRSS``) is read; the target is that it
stays within ``--budget-mb`` (10 MB) of its value after the first print.

During a print, the RSS is read too when the job reaches layer ``--layers`` A and
B (10 and 200: the jobs of 200 layers or more, the bunny, Benchy and the candle
stand): the growth from A to B, per layer, is the job's ``kb_per_layer``; the
target is that a print does not grow with the layers it printed.

Usage (from the repository root):
    .venv/bin/python bench/soak.py [--jobs 50] [--models dogbone_100x30x5,bunny]
                                   [--models-dir DIR] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import proctree
from bench.daemonproc import Daemon
from bench.slice_vs_peers import MODELS as SHARED_MODELS
from hostd.api import ControlClient, ControlError, Snapshot

MODELS = ("dogbone_100x30x5", "cube20_xyz", "featuretype_mm", "rocker_arm", "candle_stand",
          "bunny")
RETUNE = {"infill.density": 0.35}
POLL_S = 0.2


@dataclass(frozen=True)
class SoakSetup:
    """The daemon's configuration: the defaults, the simulated printer at full speed."""

    settle_s: float = 0.3
    baud: int = 250000
    slice_process: bool = True  # [runner] slice_process

    def toml(self, jobs: Path, state: Path) -> str:
        """The daemon configuration file's text."""
        return (
            f'[jobs]\nfolder = "{jobs}"\nsettle_s = {self.settle_s}\n\n'
            f'[state]\nfolder = "{state}"\n\n'
            '[printer]\nport = "sim"\n\n'
            f"[simulator]\ntime_scale = 0.0\nbaud = {self.baud}\n\n"
            f"[runner]\nslice_process = {'true' if self.slice_process else 'false'}\n"
        )


@dataclass(frozen=True)
class JobRow:
    """One job of the soak: what was done to it, how it ended, the RSS after it."""

    index: int
    model: str
    action: str  # "print", "cancel" or "retune"
    outcome: str  # "done", "cancelled" or "failed"
    seconds: float
    rss_mb: float
    kb_per_layer: float | None = None  # RSS growth from layer A to layer B, per layer
    anon_mb: float | None = None  # of the RSS: anonymous memory (heaps, Python's arenas)
    file_mb: float | None = None  # of the RSS: pages of files (the libraries' code)
    heap: dict[str, object] | None = None  # --heap-probe: the C heap's arenas, after a trim
    # the daemon's child processes (the fork server the slicing processes come from, the
    # resource tracker; a print's slicing process left running would show here): their
    # count and proportional set size (PSS: shared pages split between the sharers)
    helpers: int | None = None
    helpers_pss_mb: float | None = None


def rss_mb(pid: int, field: str = "VmRSS") -> float:
    """Resident set size of process ``pid``, in MB (``VmRSS``; ``RssAnon``: its anonymous
    memory, ``RssFile``: its pages of files, from ``/proc/PID/status``)."""
    with open(f"/proc/{pid}/status", encoding="ascii") as handle:
        for line in handle:
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError(f"no {field} for process {pid}")


def action_of(index: int, cancel_every: int, retune_at: int) -> str:
    """What the soak does to job ``index``: cancel it, retune it, or let it print."""
    if index == retune_at:
        return "retune"
    if cancel_every > 0 and index % cancel_every == cancel_every - 1:
        return "cancel"
    return "print"


def outcomes(daemon: Daemon) -> int:
    """Jobs ended so far: summaries in ``done/`` and errors in ``failed/``."""
    jobs = daemon.jobs
    return (len(list((jobs / "done").glob("*.summary.txt")))
            + len(list((jobs / "failed").glob("*.error.txt"))))


async def status(socket: Path) -> Snapshot:
    async with ControlClient(str(socket)) as client:
        return await client.status()


async def command(socket: Path, cmd: str, **args: object) -> dict[str, object]:
    async with ControlClient(str(socket)) as client:
        return await client.request(cmd, **args)


async def run_job(daemon: Daemon, model: Path, action: str, timeout: float,
                  layers: tuple[int, int] = (10, 200)) -> tuple[str, float | None]:
    """Drop ``model``, act on it once it prints layer 1 (cancel, retune), wait until it
    ended and the daemon is idle; returns ``done``, ``cancelled`` or ``failed``, and
    the RSS growth per layer (kB) between layers ``layers`` (None: not reached)."""
    socket = daemon.state / "hostd.sock"
    seen: dict[int, tuple[int, float]] = {}  # A or B -> (layer read at, RSS MB)
    ended = outcomes(daemon)
    failed_before = set((daemon.jobs / "failed").glob("*.error.txt"))
    daemon.drop(model)
    deadline = time.monotonic() + timeout
    acted = action == "print"
    while outcomes(daemon) == ended:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{model.name}: not ended after {timeout:.0f} s")
        if not daemon.alive():
            raise RuntimeError(f"the daemon exited: {daemon.log_tail()}")
        snap = await status(socket)
        if snap.job is not None and snap.state in ("printing", "paused"):
            for mark in layers:
                if mark not in seen and snap.job.layer >= mark:
                    seen[mark] = (snap.job.layer, rss_mb(daemon.pid))
        if (not acted and snap.state == "printing" and snap.job is not None
                and snap.job.layer >= 1):
            try:
                if action == "cancel":
                    await command(socket, "cancel")
                else:
                    await command(socket, "set", settings=RETUNE)
            except ControlError as exc:  # the job ended meanwhile: a plain print
                print(f"  {action} refused: {exc}", file=sys.stderr)
            acted = True
        await asyncio.sleep(POLL_S)
    while (await status(socket)).state != "idle":
        await asyncio.sleep(POLL_S)
    growth = None
    if len(seen) == 2:
        (at_a, rss_a), (at_b, rss_b) = seen[layers[0]], seen[layers[1]]
        growth = round((rss_b - rss_a) * 1024 / max(at_b - at_a, 1), 1)
    errors = set((daemon.jobs / "failed").glob("*.error.txt")) - failed_before
    if not errors:
        return "done", growth
    text = next(iter(errors)).read_text(errors="replace")
    return ("cancelled" if "cancel" in text else "failed"), growth


HEAP_PROBE = Path(__file__).resolve().parent / "heapprobe"


def heap_probe(pid: int, out: Path, timeout: float = 10.0) -> dict[str, object]:
    """Ask the daemon's heap probe (``bench/heapprobe``) for a reading: its next line
    of ``out``."""
    before = out.read_text().count("\n") if out.exists() else 0
    os.kill(pid, signal.SIGUSR2)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        lines = out.read_text().splitlines() if out.exists() else []
        if len(lines) > before:
            reading: dict[str, object] = json.loads(lines[before])
            return reading
        time.sleep(0.1)
    raise RuntimeError("the heap probe did not answer (is bench/heapprobe on PYTHONPATH?)")


def with_heap_probe(out: Path) -> None:
    """Daemons started from now on load the heap probe and write its readings to ``out``."""
    os.environ["HOSTD_HEAPPROBE"] = str(out)
    path = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = str(HEAP_PROBE) + (os.pathsep + path if path else "")


async def soak(args: argparse.Namespace) -> list[JobRow]:
    models = [args.models_dir / (name if Path(name).suffix else f"{name}.stl")
              for name in args.models.split(",")]
    missing = [m for m in models if not m.exists()]
    if missing:
        raise SystemExit(f"missing models: {', '.join(map(str, missing))}")
    rows: list[JobRow] = []
    if args.heap_probe:
        args.heap_probe.unlink(missing_ok=True)
        with_heap_probe(args.heap_probe)
    with Daemon(SoakSetup(baud=args.baud, slice_process=not args.slice_in_daemon)) as daemon:  # type: ignore[arg-type]
        daemon.wait_ready()
        daemon.wait_warm()
        helpers = proctree.descendants(daemon.pid)
        print(f"idle: {rss_mb(daemon.pid):.1f} MB (anonymous "
              f"{rss_mb(daemon.pid, 'RssAnon'):.1f}, files {rss_mb(daemon.pid, 'RssFile'):.1f}); "
              f"{len(helpers)} child processes, PSS "
              f"{proctree.tree_pss_mb(daemon.pid, include_root=False):.1f} MB",
              flush=True)
        for index in range(args.jobs):
            model = models[index % len(models)]
            action = action_of(index, args.cancel_every, args.retune_at)
            started = time.monotonic()
            outcome, growth = await run_job(daemon, model, action, args.timeout, args.layers)
            seconds = time.monotonic() - started
            await asyncio.sleep(args.settle)  # the job's last threads and files let go
            helpers = proctree.descendants(daemon.pid)
            row = JobRow(index, model.stem, action, outcome, round(seconds, 1),
                         round(rss_mb(daemon.pid), 1), growth,
                         round(rss_mb(daemon.pid, "RssAnon"), 1),
                         round(rss_mb(daemon.pid, "RssFile"), 1),
                         heap_probe(daemon.pid, args.heap_probe) if args.heap_probe else None,
                         len(helpers),
                         round(proctree.tree_pss_mb(daemon.pid, include_root=False), 1))
            rows.append(row)
            first = rows[0].rss_mb
            during = "" if growth is None else (
                f", layers {args.layers[0]}-{args.layers[1]}: {growth:+.1f} kB/layer")
            print(f"{index:3d} {model.stem:18s} {action:6s} {outcome:9s} {seconds:7.1f} s "
                  f"RSS {row.rss_mb:6.1f} MB ({row.rss_mb - first:+.1f}; anonymous {row.anon_mb}, "
                  f"files {row.file_mb}); {row.helpers} child processes, PSS "
                  f"{row.helpers_pss_mb} MB{during}", flush=True)
            if row.heap is not None:
                print(f"    heap after a trim: {json.dumps(row.heap['arenas'])}", flush=True)
    return rows


def summary(rows: list[JobRow], budget_mb: float, cycle: int) -> dict[str, object]:
    """After the first job's RSS, the largest and the last difference, and the verdict;
    the same after the first ``cycle`` jobs (each model printed once: the largest
    job's working set is then in the heap, and what grows after it is a leak)."""
    first = rows[0].rss_mb
    later = [r.rss_mb - first for r in rows[1:]] or [0.0]
    seen = rows[min(cycle, len(rows)) - 1].rss_mb
    after_cycle = [r.rss_mb - seen for r in rows[cycle:]] or [0.0]
    per_layer = [r.kb_per_layer for r in rows if r.kb_per_layer is not None]
    anon = [r.anon_mb for r in rows if r.anon_mb is not None]
    files = [r.file_mb for r in rows if r.file_mb is not None]
    return {
        "jobs": len(rows),
        "after_first_mb": first,
        "last_mb": rows[-1].rss_mb,
        "max_above_first_mb": round(max(later), 1),
        "min_below_first_mb": round(min(later), 1),
        "after_each_model_once_mb": seen,
        "max_above_that_mb": round(max(after_cycle), 1),
        "budget_mb": budget_mb,
        "within_budget": max(abs(v) for v in later) <= budget_mb,
        # the same split: anonymous memory (heaps) and pages of files (code first run)
        "anon_max_above_first_mb": round(max(anon) - anon[0], 1) if anon else None,
        "files_max_above_first_mb": round(max(files) - files[0], 1) if files else None,
        "kb_per_layer_during_print": {
            "jobs": len(per_layer),
            "median": round(sorted(per_layer)[len(per_layer) // 2], 1) if per_layer else None,
            "max": max(per_layer) if per_layer else None,
        },
        "child_processes_max": max((r.helpers or 0) for r in rows),
        "child_processes_pss_mb": [min((r.helpers_pss_mb or 0.0) for r in rows),
                                   max((r.helpers_pss_mb or 0.0) for r in rows)],
        "outcomes": {o: sum(r.outcome == o for r in rows) for o in ("done", "cancelled",
                                                                        "failed")},
    }


def _layer_pair(text: str) -> tuple[int, int]:
    """``A,B`` with ``0 <= A < B``."""
    try:
        first, last = (int(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("expected A,B (two layer numbers)") from None
    if not 0 <= first < last:
        raise argparse.ArgumentTypeError("expected 0 <= A < B")
    return first, last


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=50, help="prints back to back (50)")
    parser.add_argument("--models", default=",".join(MODELS),
                        help="model names (without .stl; G-code files with .gcode), in turn")
    parser.add_argument("--models-dir", type=Path, default=SHARED_MODELS,
                        help="folder of the shared models")
    parser.add_argument("--cancel-every", type=int, default=7,
                        help="cancel every N-th job once it prints layer 1 (0: none)")
    parser.add_argument("--retune-at", type=int, default=4,
                        help="the job retuned mid-print (index from 0; -1: none)")
    parser.add_argument("--baud", type=int, default=250000,
                        help="the simulated wire (0: unlimited)")
    parser.add_argument("--budget-mb", type=float, default=10.0)
    parser.add_argument("--settle", type=float, default=1.0,
                        help="seconds idle before RSS is read")
    parser.add_argument("--timeout", type=float, default=1800.0, help="per job, seconds")
    parser.add_argument("--layers", type=_layer_pair, default=(10, 200),
                        help="A,B: the layers between which a print's RSS growth is read "
                             "(10,200)")
    parser.add_argument("--slice-in-daemon", action="store_true",
                        help="[runner] slice_process = false: every layer sliced in the daemon")
    parser.add_argument("--json", type=Path, help="write the rows and the summary here")
    parser.add_argument("--heap-probe", type=Path, metavar="FILE",
                        help="load bench/heapprobe into the daemon and, after each job, read "
                             "its C heap's arenas (in use, free) after a trim into FILE; "
                             "HOSTD_HEAPPROBE_TRACE=N adds Python's traced memory")
    args = parser.parse_args()
    if args.jobs < 1:
        parser.error("--jobs must be 1 or more")
    rows = asyncio.run(soak(args))
    result = summary(rows, args.budget_mb, len(args.models.split(",")))
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps({"rows": [asdict(r) for r in rows], "summary": result},
                                        indent=1) + "\n")
    return 0 if result["within_budget"] else 1


if __name__ == "__main__":
    sys.exit(main())
