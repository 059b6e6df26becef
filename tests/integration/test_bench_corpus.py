"""The benchmark corpus: generated the same every time; its targets checked as design.md says."""

from __future__ import annotations

from bench import corpus, corpus_table
from bench.slice_vs_peers import Measured, Row
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings


def test_corpus_models_are_deterministic_and_slice(tmp_path):
    names = ["bracket_bad_winding", "ascii_no_endsolid", "plate_five_bodies"]
    first = {p.name: p.read_bytes() for p in corpus.build(tmp_path / "a", names=names)}
    again = {p.name: p.read_bytes() for p in corpus.build(tmp_path / "b", names=names)}
    assert first == again
    assert len(first) == 3
    assert not first["ascii_no_endsolid.stl"].rstrip().endswith(b"endsolid corpus")
    plan = SlicePlan.from_file(tmp_path / "a" / "bracket_bad_winding.stl", SliceSettings(),
                               (200.0, 200.0, 200.0))
    assert any("fixed inconsistent face winding" in w for w in plan.warnings_so_far)
    five = SlicePlan.from_file(tmp_path / "a" / "plate_five_bodies.stl", SliceSettings(),
                               (200.0, 200.0, 200.0))
    assert five.body_count == 5


def _row(ours, cura, prusa, f_ours=100.0, f_cura=100.0, f_prusa=100.0, iou=(0.99, 0.98)):
    results = {
        "hostd": Measured(ok=True, wall_s=ours, filament_mm=f_ours),
        "curaengine": Measured(ok=True, wall_s=cura, filament_mm=f_cura),
        "prusaslicer": Measured(ok=True, wall_s=prusa, filament_mm=f_prusa),
    }
    return Row(model="m", faces=1, results=results, iou_vs_prusa=iou[0],
               iou_cura_vs_prusa=iou[1])


def test_targets_follow_the_design_rules():
    v = corpus_table.verdict(_row(0.9, 1.0, 2.0))
    assert v.time_ok
    assert abs(v.time_ratio - 0.9) < 1e-9
    assert not corpus_table.verdict(_row(1.1, 1.0, 2.0)).time_ok
    # a peer under 0.3 s: a slice finishing within 0.3 s is enough, whatever the peer's
    assert corpus_table.verdict(_row(0.30, 0.05, 0.2)).time_ok
    assert not corpus_table.verdict(_row(0.31, 0.05, 0.2)).time_ok
    assert not corpus_table.verdict(_row(0.34, 0.29, 0.4)).time_ok
    # filament: within 10 % of PrusaSlicer, or between the peers where they differ more
    assert corpus_table.verdict(_row(1, 1, 1, f_ours=109.0)).filament_ok
    assert not corpus_table.verdict(_row(1, 1, 1, f_ours=112.0)).filament_ok
    assert corpus_table.verdict(_row(1, 1, 1, f_ours=115.0, f_cura=120.0)).filament_ok
    # the wall: at least as close to PrusaSlicer as CuraEngine's, or 0.97 where it is closer
    assert not corpus_table.verdict(_row(1, 1, 1, iou=(0.95, 0.96))).iou_ok
    assert corpus_table.verdict(_row(1, 1, 1, iou=(0.96, 0.96))).iou_ok
    assert corpus_table.verdict(_row(1, 1, 1, iou=(0.97, 0.999))).iou_ok
    assert not corpus_table.verdict(_row(1, 1, 1, iou=(0.969, 0.999))).iou_ok
    text = corpus_table.table([_row(1.2, 1.0, 2.0)])
    assert "worst time ratio: 1.20 (m)" in text
    assert "m (time)" in text


def test_machine_speed_times_the_interpreter_and_compiled_code_in_fresh_processes() -> None:
    import sys

    from bench.measure import machine_speed, speed_line

    speed = machine_speed(sys.executable, runs=1)
    assert set(speed) == {"python_loop_s", "numpy_sort_s"}
    assert all(0.0 < s < 60.0 for s in speed.values())
    line = speed_line(speed)
    assert line.startswith("machine: Python loop ")
    assert "numpy sort" in line


def test_failure_reasons_name_the_models_relative_to_the_checkout() -> None:
    from bench.measure import RunResult
    from bench.slice_vs_peers import ROOT, summarise

    model = ROOT.parent / "shared" / "models" / "soup.stl"
    failed = RunResult(("hostd",), 2, 0.1, None, 0.0, "", f"hostd slice: {model}: not closed")
    reason = summarise([failed]).reason
    assert str(ROOT.parent) not in reason
    assert "../shared/models/soup.stl: not closed" in reason
