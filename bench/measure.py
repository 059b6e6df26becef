"""Run a command with a timeout and measure its wall time and peak resident memory."""

from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from bench import proctree

GNU_TIME = "/usr/bin/time"


@dataclass(frozen=True)
class RunResult:
    """Outcome of one measured run."""

    cmd: tuple[str, ...]
    returncode: int | None  # None when the timeout ended it
    wall_s: float  # wall time, s
    peak_rss_mb: float | None  # peak RSS of the largest process of the run, MB (10^6 bytes)
    tree_peak_mb: float  # highest sampled PSS of all the run's processes together, MB
    stdout: str
    stderr: str

    @property
    def ok(self) -> bool:
        """True when the command exited with status 0 in time."""
        return self.returncode == 0

    @property
    def rss_mb(self) -> float | None:
        """Peak memory of the run: the larger of the largest process's peak RSS and the
        sampled PSS of all its processes together (forked workers share pages)."""
        if self.peak_rss_mb is None:
            return self.tree_peak_mb or None
        return max(self.peak_rss_mb, self.tree_peak_mb)

    def reason(self) -> str:
        """One line saying why the run failed (empty when it succeeded)."""
        if self.returncode is None:
            return f"timeout after {self.wall_s:.0f} s"
        if self.returncode == 0:
            return ""
        lines = [ln.strip() for ln in self.stderr.splitlines() if ln.strip()]
        tail = lines[-1] if lines else "no message"
        return f"exit {self.returncode}: {tail[:160]}"


def ensure_gnu_time() -> bool:
    """True when GNU time is usable; installs the Debian package `time` as root if missing."""
    if Path(GNU_TIME).exists():
        return True
    if os.geteuid() == 0 and shutil.which("apt-get"):
        subprocess.run(["apt-get", "install", "-y", "-qq", "time"], capture_output=True,
                       check=False, timeout=600)
    return Path(GNU_TIME).exists()


def run_measured(
    cmd: Sequence[str],
    timeout: float,
    env: Mapping[str, str] | None = None,
    cwd: str | Path | None = None,
) -> RunResult:
    """Run ``cmd`` to completion or ``timeout`` seconds; measure wall time and peak RSS.

    Peak RSS of the largest process comes from GNU time (``%M``) when available, otherwise
    from ``getrusage(RUSAGE_CHILDREN)`` (exact only when it grows past every earlier child);
    the summed PSS of all its processes is sampled every 0.1 s (for multi-process runs).
    The command runs in its own process group, which is killed on timeout.
    """
    full_env = dict(os.environ)
    if env:
        full_env.update(env)
    with tempfile.TemporaryDirectory(prefix="bench-time-") as tmp:
        report = Path(tmp) / "time.txt"
        use_time = Path(GNU_TIME).exists()
        argv = [GNU_TIME, "-f", "%M", "-o", str(report), *cmd] if use_time else list(cmd)
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        start = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=full_env, cwd=cwd, start_new_session=True)
        sampler = _TreeSampler(proc.pid, skip_root=use_time)
        sampler.start()
        try:
            out, err = proc.communicate(timeout=timeout)
            code: int | None = proc.returncode
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
            code = None
        wall = time.perf_counter() - start
        sampler.stop()
        rss_kb: float | None = None
        if use_time and report.exists():
            rss_kb = _last_number(report.read_text())
        elif not use_time:
            after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            rss_kb = float(after) if after > before else None
    return RunResult(
        cmd=tuple(cmd),
        returncode=code,
        wall_s=wall,
        peak_rss_mb=None if rss_kb is None else rss_kb * 1024 / 1e6,
        tree_peak_mb=sampler.peak_mb,
        stdout=out,
        stderr=err,
    )


class _TreeSampler(threading.Thread):
    """Samples the summed PSS of a process tree every ``interval`` s until stopped."""

    def __init__(self, pid: int, skip_root: bool, interval: float = 0.1) -> None:
        super().__init__(daemon=True)
        self.pid = pid
        self.skip_root = skip_root  # the root is GNU time itself: count only what it runs
        self.interval = interval
        self.peak_mb = 0.0
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.wait(self.interval):
            total = proctree.tree_pss_mb(self.pid, include_root=not self.skip_root)
            self.peak_mb = max(self.peak_mb, total)

    def stop(self) -> None:
        self._stop_event.set()
        self.join()


def _last_number(text: str) -> float | None:
    """The last line of GNU time's report that is a number (it may prepend a status line)."""
    for line in reversed(text.strip().splitlines()):
        try:
            return float(line.strip())
        except ValueError:
            continue
    return None


_PYTHON_LOOP = ("import time\nt = time.perf_counter()\nx = 0\nfor i in range(2_000_000):\n"
                "    x += i\nprint(time.perf_counter() - t)")
_NUMPY_SORT = ("import time, numpy as np\na = np.random.default_rng(1).random(4_000_000)\n"
               "t = time.perf_counter()\na.sort()\nprint(time.perf_counter() - t)")


def machine_speed(python: str, runs: int = 3) -> dict[str, float]:
    """The machine's speed now, to set runs of one benchmark at different times side by
    side: seconds of a fixed pure-Python loop (the interpreter: most of our slicing) and
    of a numpy sort of 4 M floats (compiled code, as the peers are), medians of ``runs``
    fresh processes of ``python``."""
    import statistics

    def seconds(code: str) -> float:
        out = subprocess.run([python, "-c", code], capture_output=True, text=True, check=True,
                             timeout=60)
        return float(out.stdout.strip())

    return {
        "python_loop_s": statistics.median(seconds(_PYTHON_LOOP) for _ in range(runs)),
        "numpy_sort_s": statistics.median(seconds(_NUMPY_SORT) for _ in range(runs)),
    }


def speed_line(speed: dict[str, float]) -> str:
    """:func:`machine_speed` as one line."""
    return (f"machine: Python loop {speed['python_loop_s']:.3f} s, numpy sort "
            f"{speed['numpy_sort_s']:.3f} s, load average {os.getloadavg()[0]:.2f}")
