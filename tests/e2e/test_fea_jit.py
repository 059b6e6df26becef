"""Stress jobs just in time: the analysis runs beside the first layers; a resume reads it back."""

from __future__ import annotations

import sqlite3
import subprocess
from pathlib import Path

import trimesh
from support.daemon_process import sim_config
from support.paths import HOSTD, ROOT
from support.slicer_helpers import write_mesh

CASE = """
[[fixed]]
box = [[0, 0, 0], [0, 12, 4]]
[[force]]
box = [[50, 0, 0], [50, 12, 4]]
newtons = [0, 40, 0]
"""
SETTINGS = "fea.mesh_size = 1.0\nlayer_height = 0.25\nfirst_layer_height = 0.25\n"


def job_row(state: Path) -> tuple[str, int]:
    db = sqlite3.connect(state / "jobs.sqlite3")
    try:
        row = db.execute("SELECT state, layer FROM jobs WHERE seq = 1").fetchone()
    finally:
        db.close()
    return (row[0], row[1]) if row else ("", -1)


def drop_part(hostd, folder: Path) -> None:
    bar = trimesh.creation.box((50.0, 12.0, 4.0))
    bar.apply_translation([25.0, 6.0, 2.0])
    stl = write_mesh(bar, folder / "source.stl")
    hostd.drop(SETTINGS.encode(), "arm.toml")
    hostd.drop(CASE.encode(), "arm.load.toml")
    hostd.drop(stl, "arm.stl")


def test_a_stress_job_starts_before_its_analysis_and_a_resume_reads_the_cache(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.01, extra="[runner]\nlookahead = 2\n"))
    drop_part(hostd, tmp_path)
    hostd.wait_for(lambda: "stress analysis: running beside the first layers" in hostd.log(),
                   60, "the analysis to start beside the print")
    cache = hostd.state / "fea"
    hostd.wait_for(lambda: list(cache.glob("stress-*.npz")), 120, "the analysis")
    hostd.wait_for(lambda: job_row(hostd.state)[0] == "printing"
                   and job_row(hostd.state)[1] >= 1, 120, "a printed layer")
    hostd.kill9()
    assert job_row(hostd.state)[0] == "printing"
    hostd.start()
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    resumed = subprocess.run(
        [*HOSTD, "resume", "1", "--config", str(hostd.config)], capture_output=True, text=True,
        cwd=hostd.config.parent, timeout=30, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    summary = hostd.jobs / "done" / "arm.summary.txt"
    hostd.wait_for(summary.exists, 300, "the resumed job done")
    text = summary.read_text()
    assert "stress analysis:" in text, text
    assert "(cached)" in text, text
    assert len(list(cache.glob("stress-*.npz"))) == 1
