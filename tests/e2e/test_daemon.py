"""The daemon's commands over the control socket: cancel an object, retune, pause, cancel, queue."""

from __future__ import annotations

import re
import sqlite3
import subprocess
from pathlib import Path

import pytest
from support.daemon_helpers import (
    command,
    commands,
    layer_commands,
    printing_layer,
    small_box,
    status,
    two_bodies,
)
from support.daemon_process import sim_config
from support.gcode_lines import commands_of, executed_job_lines
from support.paths import DATA, HOSTD, ROOT
from support.waiting import wait_until

from hostd.api import ControlError
from hostd.jobs.jobstore import JobStore
from slicer.paths.arcs import for_printer
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


def pid_alive(pid: int) -> bool:
    """True while process ``pid`` runs (a zombie not yet reaped counts as ended)."""
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def job_state(state: Path, job: str) -> tuple[str, int]:
    db = sqlite3.connect(state / "jobs.sqlite3")
    try:
        row = db.execute("SELECT state, layer FROM jobs WHERE seq = ?", (int(job),)).fetchone()
    finally:
        db.close()
    return (row[0], row[1]) if row else ("", -1)


def test_cancel_object_and_retune_mid_print_survive_a_crash_and_resume(daemon, tmp_path):
    model = two_bodies(tmp_path / "pair.stl")
    hostd = daemon(sim_config(time_scale=0.01, extra="[runner]\nlookahead = 2\n"))
    socket = hostd.state / "hostd.sock"
    hostd.drop(model, "pair.stl")
    hostd.wait_for(printing_layer(socket, 1), 60, "layer 1 printing")
    # dropped on an idle printer: the plan was made while the file settled, and the
    # G-code checked against a fresh slice at the end is the same, byte for byte
    assert "whole-model pass made while the file settled" in hostd.log()
    # the layers are sliced in a process of the print's own, which ends with the daemon
    child = int(re.search(r"layers sliced in process (\d+)", hostd.log()).group(1))

    with pytest.raises(ControlError, match="does not exist"):
        command(socket, "cancel_object", object=5)
    with pytest.raises(ControlError, match="layer_height"):
        command(socket, "set", settings={"layer_height": 0.3})
    with pytest.raises(ControlError, match=r"infill\.density"):
        command(socket, "set", settings={"infill.density": 3})
    cancelled = command(socket, "cancel_object", object=1)
    retuned = command(socket, "set", settings={"infill.density": 0.6})
    first_cancelled, first_retuned = cancelled["from_layer"], retuned["from_layer"]
    assert 2 <= first_cancelled <= first_retuned < 50
    snap = hostd.wait_for(printing_layer(socket, first_retuned + 1), 60, "the retuned layers")
    assert snap.job is not None
    assert snap.job.layers == 50
    assert 0 <= snap.job.layers_ready_ahead <= 2
    # checkpoints are committed by their own writer, a moment after the status moves on
    hostd.wait_for(lambda: job_state(hostd.state, "1")[1] >= first_retuned, 30,
                   "the checkpoint of the first retuned layer")
    hostd.kill9()
    wait_until(lambda: not pid_alive(child), 30, "the slicing process ended with the daemon")

    hostd.start()
    assert job_state(hostd.state, "1")[0] == "interrupted"
    hostd.wait_for(socket.exists, 10, "the control socket")
    reply = command(socket, "resume_job", job="pair.stl")
    assert reply["from_layer"] > first_retuned
    hostd.wait_for(lambda: (hostd.jobs / "done" / "pair.summary.txt").exists(), 90, "done")
    resumed = int(re.findall(r"layers sliced in process (\d+)", hostd.log())[-1])
    assert resumed != child
    wait_until(lambda: not pid_alive(resumed), 30, "the slicing process ended with the print")
    assert hostd.stop() == 0

    store = JobStore(hostd.state / "jobs.sqlite3")
    assert store.settings_changes("1") == [(first_retuned, {"infill.density": 0.6})]
    assert store.cancelled_objects("1") == [(1, first_cancelled)]
    store.close()

    base = for_printer(SliceSettings(), {"ARCS"})  # the simulator reports ARCS
    plan = SlicePlan.from_file(model, base)
    dense = plan.with_settings(SliceSettings.from_mapping({"infill.density": 0.6}, base=base))
    expected = commands(plan.start_gcode())
    expected += layer_commands(lambda index: dense if index >= first_retuned else plan,
                               lambda index: frozenset({1}) if index >= first_cancelled
                               else frozenset(), plan.layer_count)
    expected += commands(dense.end_gcode())
    assert commands_of(hostd.jobs / "done" / "pair.gcode") == expected
    # the changes really changed the G-code
    late = first_retuned + 1
    assert plan.layer_gcode(late) != dense.layer_gcode(late)
    assert len(plan.layer_gcode(late, frozenset({1}))) < len(plan.layer_gcode(late))


def test_pause_resume_cancel_and_queue_commands(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.01))
    socket = hostd.state / "hostd.sock"
    hostd.wait_for(socket.exists, 10, "the control socket")
    with pytest.raises(ControlError, match="no job is printing"):
        command(socket, "pause")
    hostd.drop(DATA / "dogbone_100x30x5.stl", "first.stl")
    hostd.wait_for(printing_layer(socket, 0), 60, "printing")
    box = small_box(tmp_path / "box.stl")
    for name in ("a", "b", "c"):
        hostd.drop(box, f"{name}.stl")
    hostd.wait_for(lambda: len(status(socket).queue) == 3, 10, "three queued")
    assert status(socket).queue == ("a.stl", "b.stl", "c.stl")
    command(socket, "queue_move", job="c.stl", index=0)
    assert status(socket).queue == ("c.stl", "a.stl", "b.stl")
    command(socket, "queue_remove", job="a.stl")
    command(socket, "queue_remove", job="b.stl")
    assert status(socket).queue == ("c.stl",)
    assert "removed from the queue" in (hostd.jobs / "failed" / "a.error.txt").read_text()

    command(socket, "pause")
    hostd.wait_for(lambda: status(socket).state == "paused", 5, "paused")
    with pytest.raises(ControlError, match="already paused"):
        command(socket, "pause")
    # the printer empties the lines already sent, then lifts the nozzle; that nothing of
    # the job is sent while paused shows in the log below: the lift, then the return
    park = ["G91", "G1 Z5.00 F600", "G90", "M83"]
    hostd.wait_for(
        lambda: executed_job_lines(hostd.state / "simulator-executed.log")[-4:] == park,
        10, "the nozzle lifted")
    acked = status(socket).job.lines_acked
    command(socket, "resume")
    hostd.wait_for(lambda: status(socket).job.lines_acked > acked, 10, "printing again")
    command(socket, "cancel")
    hostd.wait_for(lambda: (hostd.jobs / "failed" / "first.error.txt").exists(), 30, "cancel")
    assert "cancelled" in (hostd.jobs / "failed" / "first.error.txt").read_text()
    assert job_state(hostd.state, "1")[0] == "cancelled"
    hostd.wait_for(lambda: (hostd.jobs / "done" / "c.summary.txt").exists(), 120, "c printed")
    assert hostd.stop() == 0
    executed = executed_job_lines(hostd.state / "simulator-executed.log")
    tail = commands_of(hostd.jobs / "done" / "c.gcode")
    assert executed[-len(tail):] == tail
    assert executed[-len(tail) - 4:-len(tail)] == ["M104 S0", "M140 S0", "M107", "M84"]
    # the cancelled job: its own lines in order, with one lift and one return around the pause
    first = executed[:-len(tail) - 4]
    assert first[-1] == "M108"  # cancel first ends any heating wait
    first = first[:-1]
    start = first.index("G91")
    unpark = ["G91", "G1 Z-5.00 F600", "G90", "M83"]
    assert first[start:start + 8] == park + unpark
    plan = SlicePlan.from_file(DATA / "dogbone_100x30x5.stl",
                               for_printer(SliceSettings(), {"ARCS"}))
    reference = commands(plan.start_gcode())
    for index in range(plan.layer_count):
        reference += commands(plan.layer_gcode(index))
    job_lines = first[:start] + first[start + 8:]
    assert job_lines == reference[:len(job_lines)]
    # the simulator reports Cap:ARCS:1, so gcode.arcs = "auto" printed arcs
    assert any(line.startswith(("G2 ", "G3 ")) for line in job_lines)
    assert len(reference) > len(job_lines) > start


def test_sigterm_mid_print_checkpoints_and_exits_cleanly(daemon):
    hostd = daemon(sim_config(time_scale=0.01))
    socket = hostd.state / "hostd.sock"
    hostd.drop(DATA / "dogbone_100x30x5.stl", "part.stl")
    hostd.wait_for(printing_layer(socket, 2), 60, "two layers printed")
    pid = hostd.proc.pid
    hostd.proc.terminate()
    assert hostd.proc.wait(20) == 0
    hostd.proc = None
    state, layer = job_state(hostd.state, "1")
    assert state == "interrupted"
    assert layer >= 1
    assert not socket.exists()
    assert subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)],
                          capture_output=True, text=True).stdout.strip() == ""
    hostd.start()
    hostd.wait_for(socket.exists, 10, "the control socket")
    snap = status(socket)
    assert [(item.id, item.layer) for item in snap.interrupted] == [("1", layer)]
    # the queue is held while the interrupted part is on the bed
    hostd.drop(DATA / "cube20_xyz.stl", "next.stl")
    hostd.wait_for(lambda: status(socket).queue == ("next.stl",), 10, "queued")
    assert status(socket).state == "idle"
    result = subprocess.run(
        [*HOSTD, "resume", "nope", "--config", str(hostd.config)],
        capture_output=True, text=True, cwd=hostd.folder, env={"PYTHONPATH": str(ROOT)},
    )
    assert result.returncode == 2
    assert "no job 'nope'" in result.stderr
    assert hostd.stop() == 0
    store = JobStore(hostd.state / "jobs.sqlite3")
    assert [entry.to_state for entry in store.history("2")] == ["queued"]  # never started
    store.close()
    result = subprocess.run(
        [*HOSTD, "resume", "1", "--config", str(hostd.config)],
        capture_output=True, text=True, cwd=hostd.folder, env={"PYTHONPATH": str(ROOT)},
    )
    assert result.returncode == 1
    assert "no daemon is running" in result.stdout


def test_an_absent_printer_leaves_the_daemon_serving_offline(tmp_path):
    config = tmp_path / "hostd.toml"
    config.write_text('[jobs]\nsettle_s = 0.2\n[printer]\nport = "/dev/hostd-no-such-port"\n')
    proc = subprocess.Popen([*HOSTD, "run", "--config", str(config)], cwd=tmp_path,
                            stderr=subprocess.PIPE, text=True, env={"PYTHONPATH": str(ROOT)})
    try:
        socket = tmp_path / "var" / "hostd.sock"
        wait_until(socket.exists, 20, "the control socket")
        (tmp_path / "jobs" / "wait.stl").write_bytes((DATA / "cube20_xyz.stl").read_bytes())
        snap = wait_until(lambda: (s := status(socket)).queue == ("wait.stl",)
                          and s.state == "offline" and s, 20, "the job taken, offline")
        assert snap.state == "offline"
        assert not snap.printer.connected
        assert "hostd-no-such-port" in (snap.error or "")
        assert snap.queue == ("wait.stl",)  # taken and kept until a printer answers
        proc.send_signal(2)
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def test_the_queue_lists_what_waits_not_the_job_printing(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.01))
    socket = hostd.state / "hostd.sock"
    hostd.drop(small_box(tmp_path / "box.stl"), "only.stl")
    snap = hostd.wait_for(printing_layer(socket, 0), 60, "printing")
    assert snap.job.name == "only.stl"
    assert snap.queue == ()
    hostd.drop(small_box(tmp_path / "box.stl"), "next.stl")
    snap = hostd.wait_for(lambda: (s := status(socket)).queue and s, 10, "queued")
    assert snap.queue == ("next.stl",)
    assert snap.job.name == "only.stl"
    assert hostd.stop() == 0


def test_a_job_stopped_while_heating_is_queued_again_and_prints(daemon):
    hostd = daemon(sim_config(time_scale=0.05))
    hostd.drop(DATA / "cube20_xyz.stl", "warm.stl")
    hostd.wait_for(lambda: job_state(hostd.state, "1")[0] == "heating", 30, "heating")
    assert hostd.stop() == 0
    assert job_state(hostd.state, "1") == ("queued", -1)  # nothing extruded: bed still clear
    hostd.config.write_text(sim_config(time_scale=0.0))
    hostd.start()
    hostd.wait_for(lambda: (hostd.jobs / "done" / "warm.summary.txt").exists(), 60, "done")
    assert hostd.stop() == 0
    store = JobStore(hostd.state / "jobs.sqlite3")
    states = [entry.to_state for entry in store.history("1")]
    store.close()
    assert states[:4] == ["queued", "slicing", "heating", "interrupted"]
    assert states[4:] == ["queued", "slicing", "heating", "printing", "done"]


def test_emergency_stop_from_the_control_socket_halts_fails_the_job_and_reconnects(
    daemon, tmp_path
):
    hostd = daemon(sim_config(time_scale=0.01))
    socket = hostd.state / "hostd.sock"
    hostd.drop(DATA / "dogbone_100x30x5.stl", "part.stl")
    hostd.wait_for(printing_layer(socket, 0), 60, "printing")
    assert command(socket, "emergency_stop")["job"] == "1"
    failed = hostd.jobs / "failed" / "part.error.txt"
    hostd.wait_for(failed.exists, 20, "the job failed")
    assert "emergency stop" in failed.read_text()
    assert "M112" in executed_job_lines(hostd.state / "simulator-executed.log")
    # the link is opened again (the printer reset), and the next job prints
    hostd.drop(small_box(tmp_path / "box.stl"), "after.stl")
    hostd.wait_for(lambda: (hostd.jobs / "done" / "after.summary.txt").exists(), 60, "next job")
    # (the job stays current a moment after its files: its slicing process is ended)
    hostd.wait_for(lambda: status(socket).job is None, 20, "idle")
    assert command(socket, "emergency_stop")["job"] is None  # idle: halts, opens again
    hostd.wait_for(lambda: hostd.run_log().count("printer connected") == 3, 20, "reconnected")
    assert hostd.stop() == 0


def test_every_event_the_api_names_is_a_typed_job_event():
    from hostd.api import EVENTS
    from hostd.jobs.jobstate import EventKind

    assert sorted(EVENTS) == sorted(kind.value for kind in EventKind)
