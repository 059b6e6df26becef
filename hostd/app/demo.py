"""`make run`: start the daemon on the embedded default, drop the sample model, open the dashboard.

On a terminal the dashboard (`hostd tui`) opens on the demo daemon; quitting it
(``q``) stops the demo. Anywhere else a plain progress line is printed instead.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from importlib import resources
from pathlib import Path

from hostd.api import ControlClient, ControlError, Snapshot, duration
from hostd.app.liveline import LiveLine, fit_bar

SAMPLE = "dogbone_100x30x5.stl"
JOBS = Path("jobs")
STATE = Path("var")


def drop_sample(jobs: Path) -> Path:
    """Copy the shipped dogbone into the job folder atomically (write aside, then rename)."""
    jobs.mkdir(parents=True, exist_ok=True)
    target = jobs / "dogbone.stl"
    partial = jobs / ".dogbone.stl.part"
    with resources.as_file(resources.files("hostd.data") / SAMPLE) as source:
        shutil.copyfile(source, partial)
    os.replace(partial, target)
    return target


def progress_line(snapshot: Snapshot, columns: int = 80) -> str:
    """One line shorter than ``columns``: state, job, a bar, layer N of M, hotend and ETA."""
    temps = snapshot.temps
    heat = f"hotend {temps.hotend.actual:5.1f}/{temps.hotend.target:3.0f}C"
    job = snapshot.job
    if job is None:
        waiting = f"{len(snapshot.queue)} queued" if snapshot.queue else "waiting for a job"
        return f"[{snapshot.state:8}] {waiting}  {heat}"[: columns - 1]
    eta = duration(job.eta_s)
    head = f"[{snapshot.state:8}] {job.name} "
    tail = (f"{job.progress * 100:5.1f}% layer {job.layer + 1} of {job.layers}  {heat}  "
            f"ETA {eta}")
    return (head + fit_bar(job.progress, tail, columns - len(head)))[: columns - 1]


async def resume_interrupted(socket: Path) -> None:
    """Resume every job an earlier Ctrl-C interrupted, so the queue behind it moves on."""
    async with ControlClient(str(socket)) as client:
        snapshot = await client.status()
        for job in snapshot.interrupted:
            print(f"resuming {job.name} (job {job.id}) after layer {job.layer + 1}")
            try:
                await client.request("resume_job", job=job.id)
            except ControlError as exc:
                print(f"cannot resume {job.name}: {exc}")


async def watch(socket: Path, daemon: subprocess.Popen[bytes]) -> None:
    """Print a live progress line from the daemon's status until the daemon exits.

    The line is cut to the terminal's width as it is at each redraw (narrowed or not).
    """
    line = LiveLine(sys.stdout)
    resumed = False
    while daemon.poll() is None:
        try:
            if not resumed:
                await resume_interrupted(socket)
                resumed = True
            async with ControlClient(str(socket)) as client:
                async for item in client.subscribe():
                    if "status" in item:
                        line.draw(progress_line(item["status"], line.width() + 1))
                    else:
                        event = item["event"]
                        if event.get("event") in ("done", "failed", "started", "cancelled"):
                            line.clear()
                            sys.stdout.write(f"{event.get('event')}: {event.get('name', '')}\n")
                            sys.stdout.flush()
        except (ControlError, OSError):
            await asyncio.sleep(0.3)


async def watch_until_interrupted(socket: Path, daemon: subprocess.Popen[bytes]) -> None:
    """:func:`watch` until the daemon exits or Ctrl-C (SIGINT) comes.

    The signal sets an event rather than cancelling the loop's main task, so the
    demo stops the daemon even if a cancellation were lost on the way.
    """
    loop = asyncio.get_running_loop()
    interrupted = asyncio.Event()
    loop.add_signal_handler(signal.SIGINT, interrupted.set)
    try:
        watcher = asyncio.create_task(watch(socket, daemon), name="demo-watch")
        stop = asyncio.create_task(interrupted.wait(), name="demo-sigint")
        await asyncio.wait({watcher, stop}, return_when=asyncio.FIRST_COMPLETED)
        for task in (watcher, stop):
            task.cancel()
        await asyncio.wait({watcher, stop}, timeout=2.0)
    finally:
        loop.remove_signal_handler(signal.SIGINT)


async def dashboard(socket: Path, daemon: subprocess.Popen[bytes]) -> None:
    """The dashboard on the demo daemon, until it is quit."""
    from tui.app import Dashboard
    from tui.sources import SocketSource

    while not socket.exists():  # noqa: ASYNC240 (a local stat every 0.1 s)
        if daemon.poll() is not None:
            return
        await asyncio.sleep(0.1)
    with contextlib.suppress(ControlError, OSError):
        await resume_interrupted(socket)
    await Dashboard(SocketSource(str(socket))).run_async()


def main() -> int:
    """Run the demo until the dashboard is quit (or Ctrl-C); the daemon stops cleanly."""
    on_terminal = sys.stdin.isatty() and sys.stdout.isatty()
    config = resources.files("hostd.data") / "demo.toml"
    with resources.as_file(config) as config_path:
        log = (STATE / "hostd.log")
        STATE.mkdir(parents=True, exist_ok=True)
        print("hostd demo: simulated printer at 50x real time, job folder ./jobs, state ./var")
        if on_terminal:
            print(f"daemon log: {log}   the dashboard opens; q quits it and ends the demo")
        else:
            print(f"daemon log: {log}   dashboard in another terminal: .venv/bin/hostd tui")
        with open(log, "ab") as log_file:
            daemon = subprocess.Popen(
                [sys.executable, "-m", "hostd", "run", "--config", str(config_path)],
                stderr=log_file,
                stdout=log_file,
                start_new_session=True,
            )
            started = time.monotonic()
            dropped = drop_sample(JOBS)
            print(f"dropped {dropped} at t={time.monotonic() - started:.1f}s; Ctrl-C stops")
            try:
                if on_terminal:
                    asyncio.run(dashboard(STATE / "hostd.sock", daemon))
                    print("dashboard closed: stopping the daemon...")
                else:
                    asyncio.run(watch_until_interrupted(STATE / "hostd.sock", daemon))
                    if daemon.poll() is None:
                        print("\nstopping the daemon...")
            except KeyboardInterrupt:
                print("\nstopping the daemon...")
            finally:
                if daemon.poll() is None:
                    daemon.send_signal(signal.SIGINT)
                    try:
                        daemon.wait(timeout=15)
                    except subprocess.TimeoutExpired:
                        daemon.kill()
                        daemon.wait()
        print(f"daemon exited with code {daemon.returncode}")
    return 0 if daemon.returncode in (0, -signal.SIGINT) else 1


if __name__ == "__main__":
    sys.exit(main())
