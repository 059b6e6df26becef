"""Layers sliced in a process of their own (slicer.planprocess), as the daemon slices a
print's layers: the same bytes as the plan in this process, with retunes and cancelled
bodies; errors carried back; a child that dies or cannot build its plan leaves the
layers to this process; a closed child is gone."""

from __future__ import annotations

import hashlib
import logging
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.slicer_helpers import write_mesh

from hostd.jobs.schedule import LayerSchedule
from hostd.printing.etaguess import measure
from slicer.plan import SlicePlan
from slicer.planprocess import PlanProcess, PlanProcessGone, plan_warnings
from slicer.settings import SliceSettings

BED = (220.0, 220.0, 250.0)
WAIT_S = 60.0


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> Path:
    """Two boxes side by side (bodies 0 and 1), one taller than the other."""
    low = trimesh.creation.box(extents=(12.0, 12.0, 3.0))
    low.apply_translation((-10.0, 0.0, 1.5))
    tall = trimesh.creation.box(extents=(10.0, 14.0, 5.0))
    tall.apply_translation((10.0, 0.0, 2.5))
    path = tmp_path_factory.mktemp("models") / "pair.stl"
    return write_mesh(trimesh.util.concatenate([low, tall]), path)


@pytest.fixture(scope="module")
def settings() -> SliceSettings:
    return SliceSettings()


@pytest.fixture
def process(pair: Path, settings: SliceSettings):
    child = PlanProcess(pair, settings, BED)
    assert child.ready.wait(WAIT_S), child.gone
    yield child
    child.close()


def test_every_layer_is_the_same_bytes_as_here(process: PlanProcess, pair: Path,
                                                settings: SliceSettings) -> None:
    here = SlicePlan.from_file(pair, settings, BED)
    denser = SliceSettings.from_mapping({"infill.density": 0.5}, base=settings)
    for layer in range(here.layer_count):
        theirs = process.layer_code(settings, layer, frozenset(), layer - 8)
        ours = here.layer_code(layer)
        assert theirs.lines == ours.lines
        assert (theirs.time_s, theirs.filament_mm) == (ours.time_s, ours.filament_mm)
    # a retune's settings and a cancelled body, as a schedule asks for them
    middle = here.layer_count // 2
    assert process.layer_code(denser, middle, frozenset({1})).lines == \
        here.with_settings(denser).layer_code(middle, frozenset({1})).lines


def test_an_error_in_the_child_comes_back_as_raised(process: PlanProcess,
                                                     settings: SliceSettings) -> None:
    with pytest.raises(IndexError):
        process.layer_code(settings, 10_000, frozenset())
    assert process.gone is None  # the child serves on
    assert process.layer_code(settings, 0, frozenset()).lines[0] == ";LAYER:0"


def test_closed_child_is_gone_and_calls_fail(process: PlanProcess,
                                              settings: SliceSettings) -> None:
    pid = process.pid
    process.close()
    assert process.gone == "the slicing process was closed"
    with pytest.raises(PlanProcessGone):
        process.layer_code(settings, 0, frozenset())
    assert pid is not None
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)


def test_schedule_slices_in_the_child_and_takes_over_when_it_dies(
        process: PlanProcess, pair: Path, settings: SliceSettings,
        caplog: pytest.LogCaptureFixture) -> None:
    plan = SlicePlan.from_file(pair, settings, BED)
    alone = LayerSchedule(SlicePlan.from_file(pair, settings, BED), settings)
    apart = LayerSchedule(plan, settings)
    apart.slice_in(process)
    for schedule in (alone, apart):
        schedule.retune(3, {"infill.density": 0.4})
        schedule.cancel_body(0, 5)
    assert [apart.layer_gcode(i) for i in range(4)] == [alone.layer_gcode(i) for i in range(4)]
    assert apart.estimates == alone.estimates
    os.kill(process.pid, signal.SIGKILL)
    process._process.join(WAIT_S)
    with caplog.at_level(logging.WARNING, logger="hostd.jobs.schedule"):
        rest = [apart.layer_gcode(i) for i in range(4, plan.layer_count)]
    assert rest == [alone.layer_gcode(i) for i in range(4, plan.layer_count)]
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1, warnings
    assert "layers from 4 on sliced in the daemon" in warnings[0]
    apart.close()
    with pytest.raises(PlanProcessGone):  # a print that ended wants no more layers
        apart.fresh_code(0)


def test_a_child_that_cannot_build_the_plan_says_why(tmp_path: Path,
                                                     settings: SliceSettings) -> None:
    broken = tmp_path / "broken.stl"
    broken.write_bytes(b"solid nothing\nendsolid nothing\n")
    child = PlanProcess(broken, settings, BED)
    try:
        child._reader.join(WAIT_S)
        assert not child.ready.is_set()
        assert child.gone is not None
        assert child.gone.startswith("the slicing process could not build the plan: ModelError")
        with pytest.raises(PlanProcessGone):
            child.layer_code(settings, 0, frozenset())
    finally:
        child.close()


def test_whole_model_work_runs_in_the_child_with_the_same_result(
        process: PlanProcess, pair: Path, settings: SliceSettings) -> None:
    plan = SlicePlan.from_file(pair, settings, BED)
    schedule = LayerSchedule(plan, settings)
    schedule.slice_in(process)
    here = SlicePlan.from_file(pair, settings, BED)
    geometry, expected = schedule.on_plan(measure, settings), measure(here, settings)
    for field in ("walls", "solid", "sparse", "islands"):
        np.testing.assert_array_equal(getattr(geometry, field), getattr(expected, field))
    assert schedule.on_plan(plan_warnings) == here.warnings
    assert plan.warnings_so_far == []  # nothing of the model was cut here
    with pytest.raises(AttributeError, match="pickle"):  # a call the child cannot take
        process.call(lambda p: p, settings)
    os.kill(process.pid, signal.SIGKILL)
    process._reader.join(WAIT_S)
    assert process.gone is not None
    assert schedule.on_plan(plan_warnings) == here.warnings  # made here once it died
    assert plan.warnings_so_far == here.warnings
    schedule.close()
    with pytest.raises(PlanProcessGone):
        schedule.on_plan(plan_warnings)


def test_a_child_reading_other_bytes_than_the_parent_builds_no_plan(
        tmp_path: Path, pair: Path, settings: SliceSettings,
        caplog: pytest.LogCaptureFixture) -> None:
    model = tmp_path / "model.stl"
    model.write_bytes(pair.read_bytes())
    taken = hashlib.sha256(model.read_bytes()).hexdigest()
    same = PlanProcess(model, settings, BED, sha256=taken)
    try:
        assert same.wait_ready(WAIT_S), same.gone
    finally:
        same.close()
    model.write_bytes(pair.read_bytes() + b"\0")  # rewritten since the job took it
    changed = PlanProcess(model, settings, BED, sha256=taken)
    try:
        assert not changed.wait_ready(WAIT_S)
        assert changed.gone == ("the slicing process could not build the plan: ValueError: "
                                "the file changed since the job took it")
        plan = SlicePlan.from_file(pair, settings, BED)
        schedule = LayerSchedule(plan, settings)
        schedule.slice_in(changed)
        with caplog.at_level(logging.WARNING, logger="hostd.jobs.schedule"):
            lines = [schedule.layer_gcode(i) for i in range(3)]
        assert lines == [plan.layer_gcode(i) for i in range(3)]  # made here instead
        warnings = [r.getMessage() for r in caplog.records]
        assert warnings == ["layers from 0 on sliced in the daemon: the slicing process "
                            "could not build the plan: ValueError: the file changed since "
                            "the job took it"]
    finally:
        changed.close()
