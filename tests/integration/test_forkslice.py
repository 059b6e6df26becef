"""Layers sliced in forked workers, an engine of the layer window: the same bytes as in one
process, errors carried back, the window's depth bounding what the workers make."""

from __future__ import annotations

import os
import time
from collections.abc import Iterator

import pytest
from support.slicer_helpers import box_stl

from slicer.errors import ModelError
from slicer.forkslice import ForkedLayers, LayerText, per_layer
from slicer.output import gcodefile
from slicer.output.gcodefile import _chunks, _layer_text, write_gcode
from slicer.pipeline import LayerWindow
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")


def forked_layers(layer, tasks: list[tuple[int, int]], workers: int, depth: int = 8
                  ) -> Iterator[LayerText]:
    """The layers of ``tasks`` through the window with forked workers as its engine."""
    with ForkedLayers(per_layer(layer), tasks, workers) as engine:
        window = LayerWindow(engine.submit, tasks[-1][1], depth, first=tasks[0][0])
        try:
            yield from window
        finally:
            window.close()


def meet(folder, count: int = 2, timeout_s: float = 30.0) -> None:
    """Wait (in a worker) until ``count`` processes have called this with ``folder``:
    the first layer each worker makes, so that every worker is sure to take a task."""
    (folder / str(os.getpid())).touch()
    deadline = time.monotonic() + timeout_s
    while len(list(folder.iterdir())) < count and time.monotonic() < deadline:
        time.sleep(0.005)


@pytest.fixture(scope="module")
def tall_box(tmp_path_factory) -> SlicePlan:
    path = box_stl(tmp_path_factory.mktemp("box") / "box.stl", (12.0, 8.0, 14.0))
    return SlicePlan.from_file(path, SliceSettings())


def test_one_and_two_workers_write_the_same_bytes(
    tall_box: SlicePlan, tmp_path, monkeypatch
) -> None:
    forks: list[int] = []
    fork = os.fork

    def counted() -> int:
        forks.append(1)
        return fork()

    one = write_gcode(tall_box, tmp_path / "one.gcode", workers=1)
    assert forks == []
    # a box is too quick to fork for: the workers are forced here
    monkeypatch.setattr(gcodefile, "_FORK_WORTH", 0.0)
    monkeypatch.setattr(os, "fork", counted)
    two = write_gcode(tall_box, tmp_path / "two.gcode", workers=2)
    assert len(forks) == 2
    assert (tmp_path / "one.gcode").read_bytes() == (tmp_path / "two.gcode").read_bytes()
    assert (one.layers, one.filament_mm, one.time_s) == (two.layers, two.filament_mm, two.time_s)


@pytest.mark.parametrize(("at_once", "away"), [(0.0, 0.0), (0.0, 60.0), (60.0, 60.0)],
                         ids=["at-once-cut-away", "at-once-cut-here", "timed-here-first"])
def test_outlines_cut_away_or_here_before_forking_give_the_same_bytes(
    tmp_path, monkeypatch, at_once: float, away: float
) -> None:
    """A fresh plan's outlines are all cut before the workers fork. A model heavy to
    cut has them cut first (on two cores, half in a forked child, when heavier still)
    and every layer made by the workers; a light one has its first layers made and
    timed here. The file is the one process's, byte for byte."""
    path = box_stl(tmp_path / "box.stl", (12.0, 8.0, 40.0))
    write_gcode(SlicePlan.from_file(path, SliceSettings()), tmp_path / "one.gcode", workers=1)
    monkeypatch.setattr(gcodefile, "_FORK_WORTH", 0.0)
    monkeypatch.setattr(gcodefile, "_AT_ONCE_WORTH", at_once)
    monkeypatch.setattr(gcodefile, "_CUT_AWAY_WORTH", away)
    plan = SlicePlan.from_file(path, SliceSettings())
    used: list[str] = []
    real = plan.cut_away

    def counted(*args):
        used.append("cut_away")
        return real(*args)

    taken: list[str] = []
    take = LayerWindow.take

    def engine(self, index=None):
        taken.append(type(self.submit.__self__).__name__ if hasattr(self.submit, "__self__")
                     else "in_thread")
        return take(self, index)

    monkeypatch.setattr(plan, "cut_away", counted)
    monkeypatch.setattr(LayerWindow, "take", engine)
    write_gcode(plan, tmp_path / "two.gcode", workers=2)
    assert used == ([] if away else ["cut_away"])
    here = gcodefile._PROBE if at_once else 0  # the layers timed here
    assert taken == ["in_thread"] * here + ["ForkedLayers"] * (plan.layer_count - here)
    assert (tmp_path / "one.gcode").read_bytes() == (tmp_path / "two.gcode").read_bytes()


@pytest.mark.parametrize("at_once", [0.0, 60.0], ids=["at-once", "timed-here-first"])
def test_workers_forked_at_once_take_whole_skin_blocks(
    tmp_path, monkeypatch, at_once: float
) -> None:
    """Forked before any layer is made, the workers take one task per skin cache block
    (fewer task edges, each solved in two processes); forked after the layers timed
    here, the rest of the first block comes as one task, then whole blocks; the
    header's extras are made by a worker too, in a task after the layers'."""
    path = box_stl(tmp_path / "box.stl", (12.0, 8.0, 7.0))  # 35 layers: 3 blocks
    monkeypatch.setattr(gcodefile, "_FORK_WORTH", 0.0)
    monkeypatch.setattr(gcodefile, "_AT_ONCE_WORTH", at_once)
    plan = SlicePlan.from_file(path, SliceSettings())
    n = plan.layer_count
    handed: list[list[tuple[int, int]]] = []

    class Recorded(ForkedLayers):
        def __init__(self, make, tasks, workers) -> None:
            handed.append(list(tasks))
            super().__init__(make, tasks, workers)

    monkeypatch.setattr("slicer.forkslice.ForkedLayers", Recorded)
    write_gcode(plan, tmp_path / "two.gcode", workers=2)
    (tasks,) = handed
    assert n > 32
    first = 0 if at_once == 0.0 else gcodefile._PROBE
    expected = [(a, min(n, a + 16)) for a in range(16, n, 16)]
    # then the header's thumbnails and object definitions, a task of their own
    assert tasks == [(first, 16), *expected, (n, n + 1)]
    write_gcode(SlicePlan.from_file(path, SliceSettings()), tmp_path / "one.gcode", workers=1)
    assert (tmp_path / "one.gcode").read_bytes() == (tmp_path / "two.gcode").read_bytes()


def test_forked_layers_come_back_in_order_from_other_processes(
    tall_box: SlicePlan, tmp_path
) -> None:
    n = tall_box.layer_count
    here = [_layer_text(tall_box, i) for i in range(20)]
    pids: list[int] = []

    def layer(i: int) -> tuple[str, float, float]:
        if i in (0, 4):  # the first layer of each of the first two tasks
            meet(tmp_path)
        text, filament, seconds = _layer_text(tall_box, i)
        return f"{text};pid {os.getpid()}\n", filament, seconds

    forked = list(forked_layers(layer, list(_chunks(0, 20)), 2))
    assert n > 20
    assert len(forked) == 20
    for (text, filament, seconds), (want, want_f, want_s) in zip(forked, here, strict=True):
        body, pid_line = text.rsplit(";pid ", 1)
        pids.append(int(pid_line))
        assert (body, filament, seconds) == (want, want_f, want_s)
    assert os.getpid() not in pids
    assert len(set(pids)) == 2  # both workers sliced some


def test_a_worker_s_error_is_raised_here_and_the_workers_end() -> None:
    def layer(i: int) -> tuple[str, float, float]:
        if i == 9:
            raise ModelError(f"layer {i} cannot be sliced")
        return f";{i}\n", 0.0, 0.0

    got: list[str] = []
    with pytest.raises(ModelError, match="layer 9 cannot be sliced"):
        for text, _f, _s in forked_layers(layer, [(0, 4), (4, 8), (8, 12), (12, 16)], 2):
            got.append(text)
    assert got == [f";{i}\n" for i in range(8)]


def test_closing_early_stops_the_workers(tmp_path) -> None:
    def layer(i: int) -> LayerText:
        if i < 2:
            meet(tmp_path)
        return f"{os.getpid()}", 1.0, 0.5

    layers = forked_layers(layer, [(k, k + 1) for k in range(60)], 2)
    pids = {int(next(layers)[0]), int(next(layers)[0])}
    assert len(pids) == 2
    assert os.getpid() not in pids
    layers.close()  # kills and reaps both workers at once, with 58 layers not sliced
    for pid in pids:
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)


def test_a_slow_task_does_not_hold_up_the_tasks_after_it(tmp_path) -> None:
    """Tasks go to whichever worker is free: while one worker is held on the first
    task, the other makes every task after it (handed out in turn, half of them
    would wait behind the slow one)."""
    made = tmp_path / "made"
    made.mkdir()

    def layer(i: int) -> LayerText:
        if i == 0:  # held until the other worker has made the 11 layers after it
            deadline = time.monotonic() + 30.0
            while len(list(made.iterdir())) < 11 and time.monotonic() < deadline:
                time.sleep(0.005)
        else:
            (made / str(i)).write_text(str(os.getpid()))
        return f"{os.getpid()}", 0.0, 0.0

    tasks = [(k, k + 1) for k in range(12)]
    pids = [int(text) for text, _f, _s in forked_layers(layer, tasks, 2, depth=12)]
    assert len(pids) == 12
    assert pids[0] not in pids[1:]
    assert len(set(pids[1:])) == 1
    assert sorted(int(p.name) for p in made.iterdir()) == list(range(1, 12))


def test_a_worker_that_dies_fails_its_task_and_the_other_makes_the_rest(tmp_path) -> None:
    """A worker killed in the middle of a task fails that task's layers (the window
    raises there); the layers before it, made by the other worker, come back."""
    def layer(i: int) -> LayerText:
        if i == 5:
            os.kill(os.getpid(), 9)
        return f";{i}\n", 0.0, 0.0

    got: list[str] = []
    with pytest.raises(RuntimeError, match="ended before sending its layers"):
        for text, _f, _s in forked_layers(layer, [(k, k + 1) for k in range(10)], 2):
            got.append(text)
    assert got == [f";{i}\n" for i in range(5)]


def test_the_window_s_depth_bounds_what_the_workers_make(tmp_path) -> None:
    log = tmp_path / "made"
    log.touch()

    def layer(i: int) -> LayerText:
        with open(log, "a") as out:  # one short append per layer: the lines never mix
            out.write(f"{i}\n")
        return f";{i}\n", 0.0, 0.0

    def made() -> int:
        return len(log.read_text().split())

    taken = 0
    for text, _f, _s in forked_layers(layer, [(k, k + 1) for k in range(30)], 2, depth=4):
        taken += 1
        assert text == f";{taken - 1}\n"
        # a worker starts a layer only once the window submitted it: the one taken
        # and the 4 the window refilled
        assert made() <= taken + 4
    assert taken == 30
    assert sorted(int(i) for i in log.read_text().split()) == list(range(30))


def test_hostd_slice_takes_every_layer_from_the_layer_window(
    tall_box: SlicePlan, tmp_path, monkeypatch
) -> None:
    taken: list[str] = []
    take = LayerWindow.take

    def counted(self, index=None):
        layer = take(self, index)
        taken.append(type(self.submit.__self__).__name__ if hasattr(self.submit, "__self__")
                     else "in_thread")
        return layer

    monkeypatch.setattr(LayerWindow, "take", counted)
    write_gcode(tall_box, tmp_path / "one.gcode", workers=1)
    assert taken == ["in_thread"] * tall_box.layer_count
    taken.clear()
    monkeypatch.setattr(gcodefile, "_FORK_WORTH", 0.0)
    write_gcode(tall_box, tmp_path / "two.gcode", workers=2)
    assert len(taken) == tall_box.layer_count
    assert taken[: gcodefile._PROBE] == ["in_thread"] * gcodefile._PROBE  # timed here
    assert taken[-1] == "ForkedLayers"
