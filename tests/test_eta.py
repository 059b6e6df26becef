"""The ETA: refitted on the printer's pace, moved by a cancel at once, a mean for G-code jobs."""

from __future__ import annotations

import pytest
import trimesh

from hostd.eta import EtaModel
from hostd.schedule import LayerSchedule
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


def pair(path):
    """Two 20 x 20 x 6 mm blocks side by side (two bodies)."""
    left = trimesh.creation.box((20.0, 20.0, 6.0))
    left.apply_translation((-15.0, 0.0, 3.0))
    right = trimesh.creation.box((20.0, 20.0, 6.0))
    right.apply_translation((15.0, 0.0, 3.0))
    trimesh.util.concatenate([left, right]).export(path)
    return path


def wait_geometry(model: EtaModel) -> None:
    assert model._thread is not None
    model._thread.join(30)


def test_the_eta_follows_the_printer_pace_and_a_cancelled_body(tmp_path) -> None:
    plan = SlicePlan.from_file(pair(tmp_path / "pair.stl"), SliceSettings())
    schedule = LayerSchedule(plan, SliceSettings())
    layers = plan.layer_count
    model = EtaModel(schedule, layers, 0)
    model.start(0.0)
    assert model._thread is None  # nothing of the whole model is cut before the first layer
    clock = 0.0
    for layer in range(layers // 2):  # sliced a few ahead, printed 1.5 times slower
        schedule.layer_gcode(layer)
        schedule.layer_gcode(layer + 1)
        clock += 1.5 * schedule.estimates[layer][0]
        model.layer_done(layer, clock)
        if layer == 0:  # the geometry is measured once a layer has laid filament
            wait_geometry(model)
    estimates = model._estimates()
    assert model.pace(estimates) == pytest.approx(1.5)
    remaining = model.remaining(clock)
    assert remaining == pytest.approx(1.5 * estimates[layers // 2:].sum())
    # the unsliced layers are guessed close to what slicing them gives (same blocks)
    truth = sum(plan.layer_code(i).time_s for i in range(layers // 2, layers))
    assert remaining / 1.5 == pytest.approx(truth, rel=0.1)
    # a body cancelled from the next unsliced layer on: the guess drops at once, by about half
    schedule.cancel_body(1, layers // 2 + 2)
    after = model.remaining(clock)
    assert after < remaining * 0.65
    # time spent in the layer being printed comes off, up to that layer's share
    assert model.remaining(clock + 1.0) == pytest.approx(after - 1.0)


def test_a_gcode_job_falls_back_to_the_mean_layer_time() -> None:
    model = EtaModel(None, 10, 0)
    assert model.remaining(0.0) is None
    model.start(100.0)
    for layer in range(4):
        model.layer_done(layer, 100.0 + 5.0 * (layer + 1))
    assert model.remaining(120.0) == pytest.approx(5.0 * 6)
