"""A `hostd run` daemon in a temporary folder, for the benchmarks: start, drop, stop."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from bench.slice_vs_peers import OUR_SETTINGS, hostd_executable


@dataclass(frozen=True)
class DaemonSetup:
    """How each benchmark daemon is configured."""

    settle_s: float = 0.5
    time_scale: float = 0.0
    baud: int = 250000
    bed: tuple[float, float, float] = (200.0, 200.0, 200.0)  # as in the peers' runs
    slice_process: bool = True  # [runner] slice_process: each print sliced in a child

    def toml(self, jobs: Path, state: Path) -> str:
        """The daemon configuration file's text."""
        bed = ", ".join(f"{v:g}" for v in self.bed)
        return (
            f'[jobs]\nfolder = "{jobs}"\nsettle_s = {self.settle_s}\n\n'
            f'[state]\nfolder = "{state}"\n\n'
            f'[printer]\nport = "sim"\nbed = [{bed}]\n\n'
            f"[simulator]\ntime_scale = {self.time_scale}\nbaud = {self.baud}\n\n"
            f"[runner]\nslice_process = {'true' if self.slice_process else 'false'}\n\n"
            "[slicing]\n" + "".join(f"{kv.replace('=', ' = ', 1)}\n" for kv in OUR_SETTINGS)
        )


class Daemon:
    """A `hostd run` started in its own temporary folder, stopped on exit."""

    def __init__(self, setup: DaemonSetup) -> None:
        self.tmp = Path(tempfile.mkdtemp(prefix="hostd-bench-"))
        self.jobs = self.tmp / "jobs"
        self.state = self.tmp / "var"
        self.jobs.mkdir()
        self.state.mkdir()
        self.config = self.tmp / "hostd.toml"
        self.config.write_text(setup.toml(self.jobs, self.state))
        self.log = self.tmp / "daemon.log"
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Daemon:
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                [*hostd_executable(), "run", "--config", str(self.config)],
                stdout=log, stderr=subprocess.STDOUT, cwd=self.tmp, start_new_session=True)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)

    @property
    def pid(self) -> int:
        """Process id of the daemon."""
        assert self.proc is not None
        return self.proc.pid

    def alive(self) -> bool:
        """True while the daemon runs."""
        return self.proc is not None and self.proc.poll() is None

    def wait_ready(self, timeout: float = 30.0) -> None:
        """Wait until the control socket exists (the daemon is up); raise if it died."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not self.alive():
                raise RuntimeError(f"hostd run exited: {self.log_tail()}")
            if any(p.is_socket() for p in self.state.rglob("*")):
                time.sleep(0.3)  # let the watcher finish its first scan
                return
            time.sleep(0.05)
        raise RuntimeError(f"hostd run not ready after {timeout:.0f} s: {self.log_tail()}")

    def log_tail(self) -> str:
        """Last line of the daemon's output."""
        lines = self.log.read_text(errors="replace").strip().splitlines()
        return lines[-1][:200] if lines else "no output"

    def stop(self) -> None:
        """SIGTERM, then SIGKILL of the daemon's process group after 10 s."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()

    def wait_warm(self, timeout: float = 30.0) -> None:
        """Wait until the daemon's log says its slicer warmed up (the start-up's last
        step, some 0.2-1 s after the control socket); return at the timeout regardless."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.alive():
            if "slicer warmed up" in self.log.read_text(errors="replace"):
                return
            time.sleep(0.02)

    def drop(self, model: Path) -> float:
        """Copy ``model`` into the job folder (hidden copy, then rename); time it is whole."""
        hidden = self.jobs / f".{model.name}.part"
        shutil.copyfile(model, hidden)
        os.replace(hidden, self.jobs / model.name)
        return time.perf_counter()

    def failure(self, name: str) -> str | None:
        """The reason a job failed, if ``failed/NAME.error.txt`` exists."""
        errors = sorted((self.jobs / "failed").glob(f"{Path(name).stem}*.error.txt"))
        return errors[0].read_text(errors="replace").strip()[:200] if errors else None

    def executed_log(self) -> Path | None:
        """The simulated printer's executed-line log under the state folder, if any."""
        logs = sorted(self.state.rglob("*executed*.log"))
        return logs[0] if logs else None
