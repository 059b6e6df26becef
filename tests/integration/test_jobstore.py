"""Job store: state machine, queue order, checkpoints, retunes, recovery, kill -9 consistency."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import TRANSITIONS, JobNotFound, JobStore, TransitionError
from hostd.publishing.status import StatusHub


@pytest.fixture
def store(tmp_path: Path) -> JobStore:
    store = JobStore(tmp_path / "jobs.sqlite3")
    yield store
    store.close()


def add(store: JobStore, name: str = "part.stl"):
    return store.add(name, f"/in/{name}", f"/area/{name}", "stl", "ab" * 32, {"a": 1})


def test_add_and_read_back(store: JobStore) -> None:
    job = add(store)
    assert job.state == "queued"
    assert job.layer == -1
    assert job.settings == {"a": 1}
    assert store.get(job.id) == job
    assert store.find("part.stl").id == job.id
    with pytest.raises(JobNotFound):
        store.get("999")


def test_transitions_follow_the_state_machine(store: JobStore) -> None:
    job = add(store)
    for state in ("slicing", "heating", "printing", "paused", "printing", "done"):
        job = store.transition(job.id, state)
    assert job.state == "done"
    assert job.finished is not None
    assert job.started is not None
    with pytest.raises(TransitionError):
        store.transition(job.id, "printing")
    history = [entry.to_state for entry in store.history(job.id)]
    assert history == ["queued", "slicing", "heating", "printing", "paused", "printing", "done"]


@pytest.mark.parametrize("source", sorted(TRANSITIONS))
def test_every_forbidden_transition_is_refused(tmp_path: Path, source: str) -> None:
    paths = {
        "queued": [], "slicing": ["slicing"], "heating": ["slicing", "heating"],
        "printing": ["printing"], "paused": ["printing", "paused"], "done": ["printing", "done"],
        "failed": ["failed"], "cancelled": ["cancelled"], "interrupted": ["interrupted"],
    }
    for target in TRANSITIONS:
        store = JobStore(tmp_path / f"{source}-{target}.sqlite3")
        job = add(store)
        for step in paths[source]:
            job = store.transition(job.id, step)
        if target in TRANSITIONS[source]:
            assert store.transition(job.id, target).state == target
        else:
            with pytest.raises(TransitionError):
                store.transition(job.id, target)
            assert store.get(job.id).state == source
        store.close()


def test_queue_order_move_and_remove(store: JobStore) -> None:
    _a, b, c = (add(store, f"{n}.stl") for n in "abc")
    assert [job.name for job in store.queued()] == ["a.stl", "b.stl", "c.stl"]
    store.move(c.id, 0)
    assert [job.name for job in store.queued()] == ["c.stl", "a.stl", "b.stl"]
    store.move(c.id, 99)
    assert [job.name for job in store.queued()] == ["a.stl", "b.stl", "c.stl"]
    store.transition(b.id, "cancelled", note="removed")
    assert [job.name for job in store.queued()] == ["a.stl", "c.stl"]
    with pytest.raises(JobNotFound):
        store.move(b.id, 0)


def test_checkpoint_recover_and_resume_goes_first(store: JobStore) -> None:
    first, second, third = add(store, "one.stl"), add(store, "two.stl"), add(store, "3.stl")
    store.transition(first.id, "slicing")
    store.transition(first.id, "printing", layers=30)
    store.checkpoint(first.id, 7, 1234, 5678)
    store.transition(third.id, "slicing")
    store.transition(third.id, "heating", layers=30)  # stopped before its first layer
    reopened = JobStore(Path(store._db.execute("PRAGMA database_list").fetchone()[2]))
    # the daemon's one recovery rule: every active job interrupted, or queued again
    # when it printed nothing
    recovered = JobLife(reopened, StatusHub()).recover()
    assert [(job.id, job.state) for job in recovered] == [(first.id, "interrupted"),
                                                          (third.id, "queued")]
    job = reopened.get(first.id)
    assert (job.state, job.layer) == ("interrupted", 7)
    assert (job.lines_acked, job.gcode_bytes) == (1234, 5678)
    assert [j.id for j in reopened.interrupted()] == [first.id]
    assert [entry.to_state for entry in reopened.history(third.id)][-2:] == [
        "interrupted", "queued"]
    reopened.transition(first.id, "queued", resume_from=8)
    assert [j.id for j in reopened.queued()] == [first.id, third.id, second.id]
    reopened.close()


def test_retunes_and_cancelled_objects_are_recorded(store: JobStore) -> None:
    job = add(store)
    store.record_settings(job.id, 5, {"infill.density": 0.5})
    store.record_settings(job.id, 9, {"infill.field": "wave"})
    store.record_cancelled_object(job.id, 1, 6)
    assert store.settings_changes(job.id) == [(5, {"infill.density": 0.5}),
                                              (9, {"infill.field": "wave"})]
    assert store.cancelled_objects(job.id) == [(1, 6)]


WRITER = r"""
import sys, random
from pathlib import Path
from hostd.jobs.jobstore import JobStore
store = JobStore(Path(sys.argv[1]))
rng = random.Random(int(sys.argv[2]))
print("ready", flush=True)
while True:
    job = store.add("p.stl", "/s", "/p", "stl", "00", {})
    store.transition(job.id, "slicing")
    store.transition(job.id, "printing", layers=50)
    for layer in range(50):
        store.checkpoint(job.id, layer, layer * 10, layer * 100)
        if rng.random() < 0.05:
            store.record_settings(job.id, layer + 1, {"infill.density": 0.3})
    store.transition(job.id, rng.choice(["done", "failed", "cancelled", "interrupted"]))
"""


def recorded_jobs(db: Path) -> int:
    """Jobs committed so far to the store at ``db`` (0 while it cannot be read)."""
    try:
        raw = sqlite3.connect(db, timeout=1.0)
        try:
            return raw.execute("SELECT COUNT(*) FROM jobs").fetchone()[0]
        finally:
            raw.close()
    except sqlite3.Error:
        return 0


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill_9_at_any_instant_leaves_a_consistent_store(tmp_path: Path, seed: int) -> None:
    db = tmp_path / "jobs.sqlite3"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(db), str(seed)],
        stdout=subprocess.PIPE, cwd=Path(__file__).resolve().parents[2],
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == b"ready"
    # killed once the writer has recorded a few jobs: at a different instant per seed
    deadline = time.monotonic() + 30
    while recorded_jobs(db) < 2 * seed and time.monotonic() < deadline:
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    raw = sqlite3.connect(db)
    assert raw.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    raw.close()
    store = JobStore(db)
    jobs = store.jobs()
    assert jobs, "the writer made no progress"
    for job in jobs:
        history = store.history(job.id)
        assert history[-1].to_state == job.state  # each transition is one transaction
        assert -1 <= job.layer < 50
        assert job.lines_acked == max(job.layer, 0) * 10
    JobLife(store, StatusHub()).recover()
    assert not store.jobs("slicing", "heating", "printing", "paused")
    store.close()
