"""The owner of one print: its commands change memory, then the store, then publish a
typed event; refusals change nothing; at its end it lets go of what it owned."""

from __future__ import annotations

import gc
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import trimesh

from hostd.jobs.joblife import JobLife
from hostd.jobs.jobstore import JobStore
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.activejob import ActiveJob
from hostd.publishing.status import CommandError, StatusHub
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


@pytest.fixture(scope="module")
def plan(tmp_path_factory) -> SlicePlan:
    path: Path = tmp_path_factory.mktemp("models") / "pair.stl"
    left = trimesh.creation.box((10.0, 10.0, 2.0))
    left.apply_translation((-12.0, 0.0, 1.0))
    right = trimesh.creation.box((10.0, 10.0, 2.0))
    right.apply_translation((12.0, 0.0, 1.0))
    trimesh.util.concatenate([left, right]).export(path)
    return SlicePlan.from_file(path, SliceSettings())


@dataclass
class Layers:
    """The part of a layer source the commands read: the first layer not sliced yet."""

    next_unsliced: int = 3


class Printing:
    """Stands for the runner: the commands only ask that one streams."""

    paused = False


@dataclass
class Print:
    active: ActiveJob
    store: JobStore
    schedule: LayerSchedule
    seen: list[tuple[str, Any, Any]]  # (event, the store's record, the schedule's) when published


def start(tmp_path: Path, plan: SlicePlan) -> Print:
    store = JobStore(tmp_path / "jobs.sqlite3")
    job = store.add("pair.stl", "pair.stl", "pair.stl", "stl", "00", {})
    hub = StatusHub()
    active = ActiveJob(job, JobLife(store, hub))
    schedule = LayerSchedule(plan, SliceSettings())
    active.attach(schedule, Layers())  # type: ignore[arg-type]
    active.start(Printing())  # type: ignore[arg-type]
    seen: list[tuple[str, Any, Any]] = []

    def record(event: dict[str, Any]) -> None:
        now = active.schedule  # read through the print: the listener holds nothing of it
        assert now is not None
        seen.append((event["event"],
                     (store.cancelled_objects(job.id), store.settings_changes(job.id)),
                     (list(now.cancelled), list(now.changes))))

    hub.listen(record)
    return Print(active, store, schedule, seen)


def test_each_command_is_in_memory_and_in_the_store_before_its_event(
    tmp_path: Path, plan: SlicePlan,
) -> None:
    run = start(tmp_path, plan)
    assert run.active.cancel_object(1) == 3
    run.active.restore_object(1)
    assert run.active.retune({"infill.density": 0.4}) == 3
    retune = [(3, {"infill.density": 0.4})]
    assert run.seen == [
        ("object_cancelled", ([(1, 3)], []), ([(1, 3)], [])),
        ("object_restored", ([], []), ([], [])),
        ("retuned", ([], retune), ([], retune)),
    ]
    assert run.schedule.settings_at(3).infill_density == 0.4
    assert run.schedule.settings_at(2).infill_density != 0.4


def test_a_refused_command_changes_nothing(tmp_path: Path, plan: SlicePlan) -> None:
    run = start(tmp_path, plan)
    with pytest.raises(CommandError, match="does not exist"):
        run.active.cancel_object(2)
    run.active.cancel_object(0)
    with pytest.raises(CommandError, match="leave no object"):
        run.active.cancel_object(1)
    with pytest.raises(CommandError, match="not cancelled"):
        run.active.restore_object(1)
    with pytest.raises(CommandError):
        run.active.retune({"layer_height": 0.3})  # the geometry: refused by the schedule
    # only the cancel of body 0 went through
    assert [kind for kind, _store, _memory in run.seen] == ["object_cancelled"]
    assert run.store.settings_changes(run.active.job.id) == []
    assert run.schedule.changes == []


def test_too_late_to_restore_a_body_left_out_of_sliced_layers(
    tmp_path: Path, plan: SlicePlan,
) -> None:
    run = start(tmp_path, plan)
    run.active.cancel_object(0)
    assert run.active.source is not None
    run.active.source.next_unsliced = 5  # type: ignore[misc]
    with pytest.raises(CommandError, match="too late"):
        run.active.restore_object(0)
    assert run.schedule.cancelled == [(0, 3)]


def test_without_a_runner_or_a_schedule_commands_are_refused(
    tmp_path: Path, plan: SlicePlan,
) -> None:
    store = JobStore(tmp_path / "jobs.sqlite3")
    job = store.add("part.gcode", "part.gcode", "part.gcode", "gcode", "00", {})
    active = ActiveJob(job, JobLife(store, StatusHub()))
    with pytest.raises(CommandError, match="no job is printing"):
        active.cancel_object(0)
    active.attach(None, Layers())  # type: ignore[arg-type]
    active.start(Printing())  # type: ignore[arg-type]
    with pytest.raises(CommandError, match="G-code job cannot be retuned"):
        active.retune({"infill.density": 0.4})


def test_a_released_print_lets_go_of_what_it_owned_whoever_holds_it(
    tmp_path: Path, plan: SlicePlan,
) -> None:
    run = start(tmp_path, plan)
    owned = {"schedule": run.active.schedule, "source": run.active.source,
             "runner": run.active.runner}
    refs = {name: weakref.ref(thing) for name, thing in owned.items()}
    held = run.active  # a handler that kept the print after it ended
    del owned, run
    held.release()
    gc.collect()
    assert [name for name, ref in refs.items() if ref() is not None] == []
    with pytest.raises(CommandError, match="no job is printing"):
        held.cancel_object(0)
