"""Hunts stalls of pty streaming runs: many in parallel, under CPU load and pauses, with a
watchdog that dumps every stack and the link's and the simulator's state on no progress.

Each worker process streams a job through :class:`drivers.link.streamer.Streamer` to the
simulated printer over a real pseudo-terminal, run after run, exactly as
``tests/integration/test_drivers_streamer.py`` does (the printer's threads in the worker, or in a
forked child of it so that either side can be paused alone). The parent starts busy-loop
processes (some ``nice``d) and pauses workers and printers for a few milliseconds at
random (``SIGSTOP``/``SIGCONT``), as an overloaded scheduler would. A watchdog thread in
each worker watches the acknowledged count: with no progress for ``--stall-s`` seconds it
writes ``stall-W-R.txt`` (every thread's stack, every asyncio task's stack, the core's
fields, the transport's buffers, the event loop's registered descriptors, the last bytes
read and written, the simulator's state and threads), then ends the run. A run whose link
failed (``printer not responding (100 probes unanswered)``...) keeps the same dump, taken
when the failure surfaced, as ``fail-W-R.txt``. Each run also reports the bytes the
printer's receive buffer lost to overruns. Everything is bounded: ``--runs`` in all,
``--time-limit`` seconds.

    .venv/bin/python -m bench.stall_hunt --runs 400 --parallel 4 --busy 4 --time-limit 900
    # another revision of drivers/ (unpacked with git archive) under the same harness:
    .venv/bin/python -m bench.stall_hunt --src DIR ...
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import faulthandler
import io
import json
import math
import os
import random
import signal
import subprocess
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # support.linkrun: the virtual-clock hosts


# -- the worker: streaming runs with a watchdog ----------------------------------------------


def _short(value: Any, limit: int = 600) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} chars)"


def _fields(obj: Any, limit: int = 600) -> str:
    out = []
    for key, value in sorted(getattr(obj, "__dict__", {}).items()):
        out.append(f"  {key} = {_short(value, limit)}")
    return "\n".join(out)


def _sim_state(sim: Any) -> str:
    """The simulated printer's state as text (read from another thread: a snapshot)."""
    out = io.StringIO()
    fw, wire = sim._firmware, sim._wire
    out.write(f"executed: {len(sim.executed)}; last: {sim.executed[-5:]!r}\n")
    out.write("firmware:\n" + _fields(fw) + "\n")
    out.write("wire:\n" + _fields(wire) + "\n")
    out.write(f"wire rx lane: {_fields(wire._rx)}\nwire tx lane: {_fields(wire._tx)}\n")
    return out.getvalue()


def _sim_child(conn: Any, config: Any, log_path: str) -> None:
    """A forked child serving the printer; answers "dump" and "stop" on ``conn``."""
    from drivers.sim.printer import SimulatedPrinter

    sim = SimulatedPrinter(config)
    path = sim.start()
    conn.send((path, os.getpid()))
    while True:
        request = conn.recv()
        if request == "dump":
            buf = io.StringIO()
            try:
                buf.write(_sim_state(sim))
            except Exception:  # a racing snapshot: say so, keep the stacks
                buf.write(traceback.format_exc())
            with open(log_path + ".simstack", "w") as stack:
                faulthandler.dump_traceback(stack, all_threads=True)
            buf.write(Path(log_path + ".simstack").read_text())
            conn.send(buf.getvalue())
        elif request == "stop":
            sim.stop()
            conn.send((list(sim.executed), sim.stats().rx_overflow_bytes))
            return


class _Recorder:
    """The last bytes written and lines read, with times (wraps a transport's methods)."""

    def __init__(self, transport: Any) -> None:
        self.events: collections.deque[tuple[float, str, str]] = collections.deque(maxlen=80)
        write, readline = transport.write, transport.readline

        async def rec_write(data: bytes) -> None:
            self.events.append((time.monotonic(), "W", data.decode("latin-1")))
            await write(data)

        async def rec_readline() -> str:
            text = await readline()
            self.events.append((time.monotonic(), "R", text))
            return text

        transport.write = rec_write
        transport.readline = rec_readline


class _Probe:
    """What the watchdog thread needs of the run under way."""

    def __init__(self) -> None:
        self.link: Any = None
        self.transport: Any = None
        self.recorder: _Recorder | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.task: asyncio.Task[Any] | None = None
        self.sim: Any = None  # in-process printer
        self.sim_conn: Any = None  # or the child's pipe
        self.phase = "starting"


def _dump(probe: _Probe, path: Path, reason: str) -> None:
    """Everything known about a stuck run, into ``path``."""
    with open(path, "w") as out:
        out.write(f"{reason}\nphase: {probe.phase}\nmonotonic: {time.monotonic():.3f}\n\n")
        out.write("== threads of the streaming process\n")
        out.flush()
        faulthandler.dump_traceback(out, all_threads=True)
        out.write("\n== asyncio tasks\n")
        loop = probe.loop
        tasks_text: list[str] = []
        done = threading.Event()

        def collect() -> None:
            for task in asyncio.all_tasks():
                buf = io.StringIO()
                buf.write(f"-- {task.get_name()} {task!r}\n")
                task.print_stack(limit=20, file=buf)
                tasks_text.append(buf.getvalue())
            done.set()

        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(collect)
            if not done.wait(5.0):
                tasks_text.append("(the event loop did not run a callback in 5 s: blocked)\n")
        out.write("".join(tasks_text))
        link = probe.link
        if link is not None:
            core = link.core
            out.write(f"\n== core (state {core.state!r}, loop time "
                      f"{loop.time() if loop else 0.0:.3f})\n")
            out.write(_fields(core, 2000) + "\n")
            out.write("window:\n" + _fields(core.window, 2000) + "\n")
            out.write("streamer:\n" + _fields(link, 300) + "\n")
        transport = probe.transport
        if transport is not None:
            out.write("\n== transport\n" + _fields(transport, 1000) + "\n")
            with contextlib.suppress(Exception):
                lines = transport._lines
                waiting = lines.qsize() if hasattr(lines, "qsize") else len(lines)
                out.write(f"lines waiting: {waiting}\n")
        if loop is not None:
            with contextlib.suppress(Exception):
                registered = {fd: (key.events, key.data)
                              for fd, key in loop._selector.get_map().items()}
                out.write(f"\n== loop selector map\n{registered!r}\n")
                out.write(f"scheduled timers: {len(loop._scheduled)}, ready: {len(loop._ready)}\n")
        if probe.recorder is not None:
            out.write("\n== last bytes written (W) and lines read (R)\n")
            for at, kind, text in list(probe.recorder.events):
                out.write(f"{at:.3f} {kind} {text!r}\n")
        out.write("\n== simulated printer\n")
        try:
            if probe.sim is not None:
                out.write(_sim_state(probe.sim))
            elif probe.sim_conn is not None:
                probe.sim_conn.send("dump")
                if probe.sim_conn.poll(10.0):
                    out.write(probe.sim_conn.recv())
                else:
                    out.write("(the printer process did not answer in 10 s)\n")
        except Exception:
            out.write(traceback.format_exc())


async def _stream(probe: _Probe, lines: list[str], path: str, config: Any) -> Any:
    from drivers.link.streamer import Streamer
    from drivers.link.transport import open_transport

    transport = await open_transport(path, 250000)
    probe.transport = transport
    probe.recorder = _Recorder(transport)
    async with Streamer(transport, config) as link:
        probe.link = link
        probe.phase = "connect"
        await link.connect()
        probe.phase = "send"
        for line in lines:
            await link.send(line)
        probe.phase = "drain"
        await link.drain()
        probe.phase = "done"
    return link


def _one_run(args: argparse.Namespace, worker: int, run: int, rng: random.Random,
             out_dir: Path) -> dict[str, Any]:
    import multiprocessing

    from support.linkrun import arc_job, job_commands

    from drivers.link.streamer import StreamerConfig
    from drivers.sim.printer import SimulatedPrinter, SimulatorConfig

    config = StreamerConfig(probe_after_s=0.02, probe_retries=100, resync_quiet_s=0.01,
                            start_timeout_s=0.05, reconnect_attempts=200,
                            reconnect_delay_s=0.005, temperature_interval_s=1.0)
    sim_config = SimulatorConfig(time_scale=0.0, baud=args.baud, boot_delay_s=0.0,
                                 seed=rng.randrange(1 << 30))
    lines = arc_job(args.lines, seed=run)
    in_process = args.sim == "inproc" or (args.sim == "mixed" and run % 2 == 0)
    probe = _Probe()
    log_path = str(out_dir / f"w{worker}.simlog")
    child = None
    if in_process:
        sim = SimulatedPrinter(sim_config)
        path = sim.start()
        probe.sim = sim
        sim_pid = os.getpid()
    else:
        ctx = multiprocessing.get_context("fork")
        parent_conn, child_conn = ctx.Pipe()
        child = ctx.Process(target=_sim_child, args=(child_conn, sim_config, log_path),
                            daemon=True)
        child.start()
        path, sim_pid = parent_conn.recv()
        probe.sim_conn = parent_conn
    (out_dir / f"w{worker}.pids").write_text(f"{os.getpid()} {sim_pid}\n")
    result: dict[str, Any] = {"worker": worker, "run": run, "inproc": in_process,
                              "stalled": False, "ok": False}
    started = time.monotonic()
    finished = threading.Event()

    def watchdog() -> None:
        last, last_at = -1, time.monotonic()
        while not finished.wait(0.5):
            link = probe.link
            mark = (link.core.acked, link.core.stats.lines_sent) if link is not None else (-1, 0)
            acked = mark[0]
            if acked != last:
                last, last_at = acked, time.monotonic()
                continue
            if time.monotonic() - last_at >= args.stall_s:
                target = out_dir / f"stall-{worker}-{run}.txt"
                _dump(probe, target, f"no acknowledgement for {args.stall_s} s "
                      f"(acked {acked} of {len(lines)}, in_process printer {in_process})")
                result["stalled"] = True
                result["dump"] = str(target)
                if probe.loop is not None and probe.task is not None:
                    probe.loop.call_soon_threadsafe(probe.task.cancel)
                if not finished.wait(20.0):
                    sys.stderr.write(f"worker {worker}: loop blocked, exiting\n")
                    os._exit(3)
                return

    async def main() -> Any:
        probe.loop = asyncio.get_running_loop()
        probe.task = asyncio.current_task()
        return await _stream(probe, lines, path, config)

    guard = threading.Thread(target=watchdog, name="stall-watchdog", daemon=True)
    guard.start()
    link = None
    try:
        link = asyncio.run(main())
    except asyncio.CancelledError:
        result["error"] = "cancelled by the watchdog"
    except Exception as exc:
        result["error"] = f"{type(exc).__name__}: {exc}"
        if not result["stalled"]:
            # the link gave up (or the stream raised): the same dump as for a stall, the
            # printer still running, so the failure can be read after the run
            target = out_dir / f"fail-{worker}-{run}.txt"
            finished.set()
            _dump(probe, target, f"the stream raised {result['error']} "
                  f"(in_process printer {in_process})")
            result["dump"] = str(target)
    finally:
        finished.set()
        guard.join()
        overrun = 0
        if in_process:
            probe.sim.stop()
            executed = list(probe.sim.executed)
            overrun = probe.sim.stats().rx_overflow_bytes
        else:
            probe.sim_conn.send("stop")
            executed, overrun = (probe.sim_conn.recv() if probe.sim_conn.poll(20.0)
                                 else ([], 0))
            child.join(5.0)
            if child.is_alive():
                child.kill()
    result["overrun_bytes"] = overrun
    result["seconds"] = round(time.monotonic() - started, 2)
    if link is None and probe.link is not None:
        result["acked"] = probe.link.core.acked
    else:
        result["acked"] = link.core.acked if link is not None else None
    result["ok"] = (link is not None and job_commands(executed) == lines
                    and link.core.acked == len(lines))
    if link is not None and not result["ok"] and not result["stalled"]:
        result["error"] = result.get("error") or "executed lines differ from the job"
        done = job_commands(executed)
        first = next((i for i, (a, b) in enumerate(zip(done, lines, strict=False))
                      if a != b),
                     min(len(done), len(lines)))
        target = out_dir / f"fail-{worker}-{run}.txt"
        target.write_text(f"{result['error']}; first difference at job line {first}\n"
                          f"executed: {done[max(0, first - 3):first + 4]!r}\n"
                          f"job: {lines[max(0, first - 3):first + 4]!r}\n"
                          f"every command run: {len(executed)}\n")
        result["dump"] = str(target)
    return result


def worker_main(args: argparse.Namespace) -> None:
    out_dir = Path(args.out)
    rng = random.Random(args.worker * 7919 + args.seed)
    deadline = time.monotonic() + args.time_limit
    for run in range(args.runs):
        if time.monotonic() > deadline:
            break
        result = _one_run(args, args.worker, run, rng, out_dir)
        print(json.dumps(result), flush=True)


# -- the parent: workers, load, pauses --------------------------------------------------------


def _pids(out_dir: Path) -> list[int]:
    pids = []
    for file in out_dir.glob("w*.pids"):
        with contextlib.suppress(OSError, ValueError):
            pids += [int(p) for p in file.read_text().split()]
    return sorted(set(pids))


def _pauser(out_dir: Path, stop: threading.Event, rng: random.Random, rate: float,
            longest: float, counts: collections.Counter[str]) -> None:
    """SIGSTOP a random worker or printer for a few milliseconds, ``rate`` times a second."""
    while not stop.wait(rng.expovariate(rate)):
        pids = _pids(out_dir)
        if not pids:
            continue
        pid = rng.choice(pids)
        try:
            os.kill(pid, signal.SIGSTOP)
        except ProcessLookupError:
            continue
        try:
            time.sleep(rng.uniform(0.002, longest))
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        counts["pauses"] += 1


def parent_main(args: argparse.Namespace) -> int:
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("w*.pids"):
        old.unlink()
    src = Path(args.src).resolve() if args.src else ROOT
    env = dict(os.environ, PYTHONPATH=str(src))
    busy = []
    nices = [0, 5, 10, 19]
    for i in range(args.busy):
        busy.append(subprocess.Popen(
            ["nice", "-n", str(nices[i % len(nices)]), sys.executable, "-c", "while True: pass"]))
    per_worker = math.ceil(args.runs / args.parallel)
    workers = []
    for w in range(args.parallel):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(w),
               "--runs", str(per_worker), "--lines", str(args.lines), "--out", str(out_dir),
               "--stall-s", str(args.stall_s), "--time-limit", str(args.time_limit),
               "--sim", args.sim, "--baud", str(args.baud), "--seed", str(args.seed)]
        nice = ["nice", "-n", str(w % 3 * 5)] if args.nice_workers else []
        workers.append(subprocess.Popen(nice + cmd, env=env, cwd=str(src),
                                        stdout=subprocess.PIPE, text=True))
    stop = threading.Event()
    counts: collections.Counter[str] = collections.Counter()
    pauser = threading.Thread(target=_pauser, args=(out_dir, stop, random.Random(args.seed),
                                                    args.pause_rate, args.pause_max_s, counts),
                              daemon=True)
    if args.pause_rate > 0:
        pauser.start()
    results: list[dict[str, Any]] = []
    lock = threading.Lock()

    def collect(proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            with contextlib.suppress(json.JSONDecodeError):
                item = json.loads(line)
                with lock:
                    results.append(item)
                if item["stalled"] or not item["ok"]:
                    print(f"  worker {item['worker']} run {item['run']}: "
                          f"{'STALL' if item['stalled'] else 'FAIL'} {item.get('error', '')} "
                          f"{item.get('dump', '')}", flush=True)
                if item.get("overrun_bytes"):
                    print(f"  worker {item['worker']} run {item['run']}: receive buffer "
                          f"overrun, {item['overrun_bytes']} bytes lost", flush=True)

    readers = [threading.Thread(target=collect, args=(p,), daemon=True) for p in workers]
    for reader in readers:
        reader.start()
    started = time.monotonic()
    try:
        for proc in workers:
            left = args.time_limit + 120 - (time.monotonic() - started)
            try:
                proc.wait(timeout=max(1.0, left))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    finally:
        stop.set()
        if pauser.is_alive():
            pauser.join()
        for pid in _pids(out_dir):  # nothing left stopped
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
        for proc in busy:
            proc.kill()
            proc.wait()
        for reader in readers:
            reader.join(5.0)
    stalls = [r for r in results if r["stalled"]]
    fails = [r for r in results if not r["ok"] and not r["stalled"]]
    overruns = [r for r in results if r.get("overrun_bytes")]
    secs = sorted(r["seconds"] for r in results if r["ok"])
    median = secs[len(secs) // 2] if secs else 0.0
    print(f"{len(results)} runs of {args.lines} lines in {time.monotonic() - started:.0f} s "
          f"(src {src}, {args.parallel} workers, {args.busy} busy loops, "
          f"{counts['pauses']} pauses, printer {args.sim}): {len(stalls)} stalls, "
          f"{len(fails)} other failures, {len(overruns)} with receive-buffer overruns "
          f"({sum(r['overrun_bytes'] for r in overruns)} bytes lost); "
          f"run median {median:.2f} s, "
          f"longest {secs[-1] if secs else 0.0:.2f} s; "
          f"load average {os.getloadavg()[0]:.1f}")
    return 1 if stalls or fails else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=200, help="streaming runs in all")
    parser.add_argument("--parallel", type=int, default=4, help="worker processes")
    parser.add_argument("--lines", type=int, default=500, help="job lines per run")
    parser.add_argument("--busy", type=int, default=4, help="busy-loop processes beside")
    parser.add_argument("--nice-workers", action="store_true", help="nice workers 0/5/10")
    parser.add_argument("--pause-rate", type=float, default=5.0,
                        help="SIGSTOP/SIGCONT pauses per second (0: none)")
    parser.add_argument("--pause-max-s", type=float, default=0.15, help="longest pause")
    parser.add_argument("--stall-s", type=float, default=30.0,
                        help="no acknowledgement for this long is a stall")
    parser.add_argument("--time-limit", type=float, default=600.0, help="seconds in all")
    parser.add_argument("--sim", choices=("inproc", "process", "mixed"), default="mixed",
                        help="printer threads in the streaming process, a child, or both")
    parser.add_argument("--baud", type=int, default=0, help="simulated wire (0: unlimited)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="/tmp/stall_hunt", help="dumps and pid files")
    parser.add_argument("--src", default=None, help="tree whose drivers/ to run")
    parser.add_argument("--worker", type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:
        worker_main(args)
        return 0
    return parent_main(args)


if __name__ == "__main__":
    sys.exit(main())
