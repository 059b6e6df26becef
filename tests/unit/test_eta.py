"""The ETA: the planner's time per layer, refitted on the printer's pace, moved at once by a
cancel or a retune (the filament total too), paused time left out, a mean for G-code jobs."""

from __future__ import annotations

import re

import pytest
import trimesh

from drivers.sim.feed import simulate_feed
from hostd.jobs.schedule import LayerSchedule
from hostd.printing.eta import EtaModel
from hostd.publishing.layerview import estimate
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

SETTINGS = SliceSettings.from_mapping({"acceleration": 3000.0})


def pair(path, height: float = 3.0):
    """Two 20 x 20 mm blocks side by side (two bodies)."""
    left = trimesh.creation.box((20.0, 20.0, height))
    left.apply_translation((-15.0, 0.0, height / 2))
    right = trimesh.creation.box((20.0, 20.0, height))
    right.apply_translation((15.0, 0.0, height / 2))
    trimesh.util.concatenate([left, right]).export(path)
    return path


def box_and_cylinder(path):
    """A 20 x 20 x 3 mm block beside a cylinder 20 mm across (walls that become arcs)."""
    box = trimesh.creation.box((20.0, 20.0, 3.0))
    box.apply_translation((-15.0, 0.0, 1.5))
    cylinder = trimesh.creation.cylinder(radius=10.0, height=3.0, sections=96)
    cylinder.apply_translation((15.0, 0.0, 1.5))
    trimesh.util.concatenate([box, cylinder]).export(path)
    return path


def started(schedule: LayerSchedule) -> EtaModel:
    model = EtaModel(schedule, schedule.layer_count, 0)
    model.start(0.0)
    assert model.wait_measured(60)
    return model


def print_half(model: EtaModel, schedule: LayerSchedule, pace: float) -> tuple[int, float]:
    """Slice and 'print' the first half, one layer ahead, at ``pace`` s per estimated s."""
    clock = 0.0
    half = schedule.layer_count // 2
    for layer in range(half):
        schedule.layer_gcode(layer)
        schedule.layer_gcode(layer + 1)
        clock += pace * schedule.estimates[layer][0]
        model.layer_done(layer, clock)
    return half, clock


@pytest.mark.parametrize("arcs", ["off", "on"])
def test_a_layer_s_estimate_is_the_simulated_planner_s_time(tmp_path, arcs) -> None:
    settings = SliceSettings.from_mapping({"acceleration": 3000.0, "gcode.arcs": arcs})
    plan = SlicePlan.from_file(box_and_cylinder(tmp_path / "two.stl"), settings)
    code = plan.layer_code(5)
    moves = [line for line in code.lines if line.startswith(("G0", "G1", "G2", "G3"))]
    assert any(line.startswith(("G2", "G3")) for line in moves) == (arcs == "on")
    last = re.findall(r"X(\S+) Y(\S+)", moves[-1])[-1]
    # the nozzle waits at the layer's last point one layer down, as the estimate assumes
    lead = ["G90", "M83", f"G0 F9000 X{last[0]} Y{last[1]} Z{plan.layer_z(4):.3f}", "M400"]
    acks: list[float] = []
    result = simulate_feed(lead + code.lines, 0, acks=acks)
    planner_s = result.print_s - acks[len(lead) - 1]
    assert code.time_s == pytest.approx(planner_s, rel=0.02)


def test_the_eta_follows_the_printer_pace_and_a_cancelled_body(tmp_path) -> None:
    plan = SlicePlan.from_file(pair(tmp_path / "pair.stl"), SETTINGS)
    schedule = LayerSchedule(plan, SETTINGS)
    model = started(schedule)
    half, clock = print_half(model, schedule, 1.5)
    assert model.pace(model._estimates()) == pytest.approx(1.5)
    remaining = model.remaining(clock)
    # the layers not sliced yet are guessed close to what slicing them gives
    truth = sum(plan.layer_code(i).time_s for i in range(half, plan.layer_count))
    assert remaining / 1.5 == pytest.approx(truth, rel=0.05)
    filament = estimate(schedule, half, half + 2, remaining)["filament_total_mm"]
    # a body cancelled from the next unsliced layer on: the guess drops at once, by about half,
    # and so does the filament the job will use in all
    schedule.cancel_body(1, half + 2)
    after = model.remaining(clock)
    assert after < remaining * 0.65
    assert estimate(schedule, half, half + 2, after)["filament_total_mm"] < filament * 0.85
    # time spent in the layer being printed comes off, up to that layer's share
    assert model.remaining(clock + 1.0) == pytest.approx(after - 1.0)


def test_a_retune_moves_the_eta_at_once_and_a_pause_is_not_printing_time(tmp_path) -> None:
    plan = SlicePlan.from_file(pair(tmp_path / "pair.stl"), SETTINGS)
    schedule = LayerSchedule(plan, SETTINGS)
    model = started(schedule)
    half, clock = print_half(model, schedule, 1.0)
    before = model.remaining(clock)
    # slower walls and fill from the next unsliced layer on: the ETA grows before it is sliced
    schedule.retune(half + 1, {"print_speed": SETTINGS.print_speed / 2,
                               "wall_speed": SETTINGS.wall_speed / 2})
    slower = model.remaining(clock)
    assert slower > before * 1.4
    # paused for 100 s: the ETA does not count down, and the pace ignores the pause
    model.pause(clock)
    assert model.remaining(clock + 100.0) == pytest.approx(slower)
    model.resume(clock + 100.0)
    schedule.layer_gcode(half + 1)
    model.layer_done(half, clock + 100.0 + schedule.estimates[half][0])
    assert model.pace(model._estimates()) == pytest.approx(1.0)


def test_a_gcode_job_falls_back_to_the_mean_layer_time() -> None:
    model = EtaModel(None, 10, 0)
    assert model.remaining(0.0) is None
    model.start(100.0)
    for layer in range(4):
        model.layer_done(layer, 100.0 + 5.0 * (layer + 1))
    assert model.remaining(120.0) == pytest.approx(5.0 * 6)


def test_the_daemon_measures_only_after_the_first_layer_that_laid_filament(tmp_path) -> None:
    plan = SlicePlan.from_file(pair(tmp_path / "pair.stl"), SETTINGS)
    schedule = LayerSchedule(plan, SETTINGS)
    model = EtaModel(schedule, schedule.layer_count, 0)
    model.start(0.0, measure_now=False)
    schedule.estimates[0] = (0.5, 0.0)  # a layer that moved but laid nothing
    model.layer_done(0, 1.0)
    assert model._thread is None  # nothing of the whole model cut yet
    schedule.layer_gcode(1)
    model.layer_done(1, 2.0)
    assert model._thread is not None
    assert model.wait_measured(60)


def test_the_filament_used_and_total_follow_the_slicer_a_retune_and_a_cancel(tmp_path) -> None:
    plan = SlicePlan.from_file(pair(tmp_path / "pair.stl", height=6.0), SETTINGS)
    schedule = LayerSchedule(plan, SETTINGS)
    model = EtaModel(schedule, schedule.layer_count, 0)
    assert model.filament() is None  # nothing sliced yet
    model.start(0.0)
    assert model.wait_measured(60)
    half, _clock = print_half(model, schedule, 1.0)
    used, total = model.filament()
    truth = [plan.layer_code(i).filament_mm for i in range(plan.layer_count)]
    assert used == pytest.approx(sum(truth[:half]))  # the layers printed, as sliced
    assert total == pytest.approx(sum(truth), rel=0.05)  # the others guessed, calibrated
    # denser infill from the next unsliced layer on: more filament before it is sliced
    schedule.retune(half + 2, {"infill.density": 0.6})
    denser = model.filament()[1]
    retuned = SlicePlan.from_file(tmp_path / "pair.stl", SliceSettings.from_mapping(
        {"acceleration": 3000.0, "infill.density": 0.6}))
    expected = sum(truth[:half + 2]) + sum(retuned.layer_code(i).filament_mm
                                           for i in range(half + 2, plan.layer_count))
    assert denser > total
    assert denser == pytest.approx(expected, rel=0.08)
    # a body left out: the total drops at once, the filament used does not change
    schedule.cancel_body(1, half + 2)
    less_used, less = model.filament()
    assert less_used == pytest.approx(used)
    assert less < denser * 0.85
