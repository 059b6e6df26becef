"""The daemon as a real subprocess (`hostd run`) on a temporary job and state folder."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from support.paths import HOSTD, ROOT


class DaemonProcess:
    """`hostd run --config CFG` in a subprocess, with helpers to drop files and wait."""

    def __init__(self, folder: Path, config_text: str) -> None:
        self.folder = folder
        self.jobs = folder / "jobs"
        self.state = folder / "var"
        self.config = folder / "hostd.toml"
        self.config.write_text(config_text)
        self.log_path = folder / "daemon.log"
        self.proc: subprocess.Popen[bytes] | None = None
        self.runs = 0

    def start(self) -> DaemonProcess:
        """Start (or restart) the daemon."""
        self.runs += 1
        log = open(self.log_path, "ab")  # noqa: SIM115 - kept open by the child
        log.write(f"--- run {self.runs}\n".encode())
        log.flush()
        self.proc = subprocess.Popen(
            [*HOSTD, "run", "--config", str(self.config)],
            cwd=self.folder, stdout=log, stderr=log, env={**os.environ, "PYTHONPATH": str(ROOT)},
        )
        log.close()
        self.wait_for(lambda: "printer connected" in self.run_log(), 20, "the printer link")
        return self

    def log(self) -> str:
        """Everything every run of the daemon logged."""
        return self.log_path.read_text(errors="replace")

    def run_log(self) -> str:
        """What the latest run logged."""
        return self.log().split(f"--- run {self.runs}\n", 1)[-1]

    def drop(self, source: Path | bytes, name: str) -> Path:
        """Put a file into the job folder atomically (written aside as a dotfile, renamed)."""
        self.jobs.mkdir(parents=True, exist_ok=True)
        partial = self.jobs / f".{name}.part"
        if isinstance(source, bytes):
            partial.write_bytes(source)
        else:
            shutil.copyfile(source, partial)
        os.replace(partial, self.jobs / name)
        return self.jobs / name

    def wait_for(self, check: Callable[[], object], timeout: float, what: str) -> object:
        """Poll ``check`` until it returns something true; fail with the log on timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            result = check()
            if result:
                return result
            if self.proc is not None and self.proc.poll() is not None:
                pytest.fail(f"daemon exited ({self.proc.returncode}) waiting for {what}:\n"
                            + self.log()[-4000:])
            time.sleep(0.05)
        pytest.fail(f"timed out waiting for {what}:\n" + self.log()[-4000:])

    def stop(self, timeout: float = 20) -> int:
        """SIGINT, and wait for the exit code."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout)
        finally:
            self.proc = None

    def kill9(self) -> None:
        assert self.proc is not None
        self.proc.kill()
        self.proc.wait()
        self.proc = None

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def sim_config(
    time_scale: float = 0.0, settle_s: float = 0.2, extra: str = "", jobs_extra: str = ""
) -> str:
    """A daemon configuration on the simulated printer, ./jobs and ./var.

    ``jobs_extra`` goes into ``[jobs]``; ``extra`` (whole sections) at the end.
    """
    return (
        f"[jobs]\nsettle_s = {settle_s}\n{jobs_extra}\n"
        f"[simulator]\ntime_scale = {time_scale}\nbaud = 0\n{extra}\n"
    )
