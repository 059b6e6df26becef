"""Print history from a real daemon: records, totals, `hostd history`, the snapshot, reprint."""

from __future__ import annotations

import csv
import io
import json
import subprocess
from pathlib import Path

from support.daemon_helpers import command, printing_layer, small_box, status, two_bodies
from support.daemon_process import sim_config
from support.paths import HOSTD, ROOT

from hostd.publishing.history import History, PrintRecord


def hostd_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*HOSTD, *args], cwd=cwd, capture_output=True, text=True, timeout=60,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


def header_filament(path: Path) -> tuple[float, float]:
    lines = path.read_text().splitlines()[:20]
    mm = next(line for line in lines if line.startswith("; filament used [mm]"))
    grams = next(line for line in lines if line.startswith("; filament used [g]"))
    return float(mm.split("=")[1]), float(grams.split("=")[1])


def test_done_and_failed_jobs_are_recorded_listed_and_reprinted_alike(daemon, tmp_path) -> None:
    hostd = daemon(sim_config())
    socket = hostd.state / "hostd.sock"
    (hostd.jobs / "box.toml").write_text('layer_height = 0.3\n[infill]\ndensity = 0.35\n')
    hostd.drop(small_box(tmp_path / "box.stl"), "box.stl")
    hostd.wait_for(lambda: (hostd.jobs / "done" / "box.gcode").exists(), 60, "box printed")
    hostd.drop(b"solid junk\n", "junk.stl")
    hostd.wait_for(lambda: len(status(socket).history) == 2, 30, "two jobs in the snapshot")
    snapshot = status(socket)
    assert [(j["name"], j["outcome"]) for j in snapshot.history] == [
        ("junk.stl", "failed"), ("box.stl", "done")]

    listed = hostd_cli("history", "--json", "--config", str(hostd.config), cwd=hostd.folder)
    assert listed.returncode == 0, listed.stderr
    data = json.loads(listed.stdout)
    junk, box = (PrintRecord(**item) for item in data["jobs"])
    mm, grams = header_filament(hostd.jobs / "done" / "box.gcode")
    assert (box.outcome, box.filament_mm, box.filament_g) == ("done", mm, grams)
    assert box.layers == box.layers_done == 10  # 3 mm at 0.3 mm
    assert box.settings["layer_height"] == 0.3
    assert box.settings["infill.density"] == 0.35
    assert box.infill_field == "linear"
    assert box.retunes == []
    assert box.cancelled == []
    assert box.started is not None
    assert 0 < box.print_s <= box.total_s
    assert box.model == str(hostd.jobs / "done" / "box.stl")
    assert junk.outcome == "failed"
    assert junk.reason == (hostd.jobs / "failed" / "junk.error.txt").read_text().strip()
    totals = data["totals"]
    assert (totals["jobs"], totals["done"], totals["failed"], totals["success_rate"]) == (
        2, 1, 1, 0.5)
    assert totals["total_filament_mm"] == mm
    assert totals["longest_print_s"] == box.print_s

    table = hostd_cli("history", "--csv", "--limit", "1", "--config", str(hostd.config),
                      cwd=hostd.folder)
    rows = list(csv.DictReader(io.StringIO(table.stdout)))
    assert [(row["job_id"], row["outcome"]) for row in rows] == [("2", "failed")]
    text = hostd_cli("history", "--config", str(hostd.config), cwd=hostd.folder).stdout
    assert "2 jobs (1 done, 1 failed, 0 cancelled), success rate 50 %" in text

    again = hostd_cli("reprint", "box.stl", "--config", str(hostd.config), cwd=hostd.folder)
    assert again.returncode == 0, again.stderr
    assert "dropped again as" in again.stdout
    hostd.wait_for(lambda: (hostd.jobs / "done" / "box-1.gcode").exists(), 60, "box reprinted")
    original = (hostd.jobs / "done" / "box.gcode").read_bytes()
    assert (hostd.jobs / "done" / "box-1.gcode").read_bytes() == original
    missing = hostd_cli("reprint", "nothing.stl", "--config", str(hostd.config), cwd=hostd.folder)
    assert missing.returncode == 2
    assert "no job 'nothing.stl'" in missing.stderr
    assert hostd.stop() == 0


def test_a_cancelled_job_keeps_its_retunes_cancelled_bodies_and_filament(daemon, tmp_path) -> None:
    hostd = daemon(sim_config(time_scale=0.01))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    hostd.drop(two_bodies(tmp_path / "pair.stl"), "pair.stl")
    hostd.wait_for(printing_layer(socket, 2), 60, "layer 2 printing")
    body = command(socket, "cancel_object", object=1)
    tune = command(socket, "set", settings={"fan_speed": 0.5})
    hostd.wait_for(printing_layer(socket, body["from_layer"] + 1), 60, "past the cancel")
    command(socket, "cancel")
    hostd.wait_for(lambda: status(socket).history, 20, "the cancelled job recorded")
    hostd.stop()
    history = History(hostd.state / "history.sqlite3", readonly=True)
    (record,) = history.records()
    history.close()
    assert record.outcome == "cancelled"
    assert "cancelled at layer" in (record.reason or "")
    assert record.cancelled == [[1, body["from_layer"]]]
    assert record.retunes == [[tune["from_layer"], {"fan_speed": 0.5}]]
    assert record.layers_done >= body["from_layer"] + 1
    assert record.filament_mm > 0
    assert record.filament_g > 0
    assert record.model == str(hostd.jobs / "failed" / "pair.stl")
