"""`make run`'s demo: drops the sample, shows progress, and Ctrl-C leaves no daemon behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from support.daemon_helpers import daemon_pids

from hostd.api import JobStatus, Snapshot
from hostd.app.demo import drop_sample, progress_line


def test_sample_is_dropped_whole_under_its_final_name(tmp_path: Path) -> None:
    target = drop_sample(tmp_path / "jobs")
    assert target.name == "dogbone.stl"
    assert sorted(p.name for p in target.parent.iterdir()) == ["dogbone.stl"]
    assert target.stat().st_size == 84 + 50 * 796  # binary STL of 796 faces


def test_progress_line_shows_job_bar_and_layer() -> None:
    job = JobStatus(id="1", name="dogbone.stl", layer=5, layers=25, progress=0.2, eta_s=75)
    line = progress_line(Snapshot(state="printing", job=job), columns=120)
    assert "dogbone.stl" in line
    assert "20.0%" in line
    assert "layer 6 of 25" in line
    assert "ETA 1:15" in line
    assert "[######------" in line
    assert "waiting for a job" in progress_line(Snapshot())
    for columns in (20, 40, 60, 80, 200):
        narrow = progress_line(Snapshot(state="printing", job=job), columns=columns)
        assert len(narrow) < columns
    assert "layer 6 of 25" in progress_line(Snapshot(state="printing", job=job), columns=80)


def test_demo_prints_and_ctrl_c_stops_the_daemon(tmp_path: Path) -> None:
    demo = subprocess.Popen(
        [sys.executable, "-m", "hostd.app.demo"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )
    assert demo.stdout is not None
    seen = b""
    deadline = time.monotonic() + 60
    while b"[printing]" not in seen and time.monotonic() < deadline:
        chunk = os.read(demo.stdout.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
    assert b"started: dogbone.stl" in seen
    assert b"[printing]" in seen, seen.decode(errors="replace")[-500:]
    demo.send_signal(signal.SIGINT)
    try:
        rest, _ = demo.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        for pid in daemon_pids(tmp_path):  # leave no daemon behind, show its log
            os.kill(pid, signal.SIGKILL)
        demo.kill()
        log = (tmp_path / "var" / "hostd.log").read_text()[-3000:]
        raise AssertionError(f"the demo did not stop on Ctrl-C; daemon log:\n{log}") from None
    assert b"daemon exited with code 0" in rest
    assert demo.returncode == 0
    assert daemon_pids(tmp_path) == []
    executed = (tmp_path / "var" / "simulator-executed.log").read_text().splitlines()
    assert any(line.startswith("G1") and " E" in line for line in executed)
