"""Load cases: every refusal has its own reason, in the parser, the analysis and the daemon."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest
import trimesh
from support.daemon_process import sim_config

from hostd.jobs.loadcheck import LoadChecks
from slicer.fea.field import analyse_arrays, check_case
from slicer.fea.loadcase import LoadCaseError, parse_load_case

BAR = """
[[fixed]]
box = [[0, 0, 0], [0, 10, 3]]
[[force]]
box = [[30, 0, 0], [30, 10, 3]]
newtons = [100, 0, 0]
"""


def bar_mesh(length: float = 30.0) -> trimesh.Trimesh:
    """A 30 x 10 x 3 mm bar with its least corner at the origin."""
    mesh = trimesh.creation.box((length, 10.0, 3.0))
    mesh.apply_translation([length / 2, 5.0, 1.5])
    return mesh


PARSE_ERRORS = {
    "unknown table": ("[[forces]]\nbox = [[0,0,0],[1,1,1]]\n", "unknown table or key 'forces'"),
    "unknown key": (BAR.replace("newtons", "newton"), "unknown key 'newton'"),
    "unknown material key": ("[material]\nyoung = 3\n" + BAR, "unknown key 'young'"),
    "nothing fixed": (BAR.split("[[force]]")[1].join(["[[force]]", ""]), "nothing is fixed"),
    "no load": (BAR.split("[[force]]")[0], "no load"),
    "zero force": (BAR.replace("[100, 0, 0]", "[0, 0, 0]"), "newtons is zero"),
    "nan force": (BAR.replace("[100, 0, 0]", "[nan, 0, 0]"), "must be finite"),
    "infinite pressure": (BAR + "[[pressure]]\nbox = [[0,0,3],[30,10,3]]\nmpa = inf\n",
                          "[[pressure]] 1 mpa must be finite"),
    "zero pressure": (BAR + "[[pressure]]\nbox = [[0,0,3],[30,10,3]]\nmpa = 0\n",
                      "[[pressure]] 1 mpa is zero"),
    "short box": (BAR.replace("[[0, 0, 0], [0, 10, 3]]", "[[0, 0], [0, 10]]"), "box must be"),
    "box inside out": (BAR.replace("[[0, 0, 0], [0, 10, 3]]", "[[1, 0, 0], [0, 10, 3]]"),
                       "least"),
    "zero normal": (BAR + "normal = [0, 0, 0]\n", "normal is zero"),
    "bad poisson": ("[material]\npoisson_ratio = 0.5\n" + BAR, "poisson_ratio"),
    "bad toml": ("[[fixed]\n", "not valid TOML"),
    "zero gage": ("[test]\ngage_length_mm = 0\n" + BAR, "gage_length_mm must be positive"),
    "unknown reading": ("[test]\nreads = 'strain'\n" + BAR,
                        "reads must be one of extensometer, stiffness"),
    "unknown test key": ("[test]\ngage = 20\n" + BAR, "[test]: unknown key 'gage'"),
}


def test_the_test_table_names_the_gage_length_and_the_headline() -> None:
    from slicer.fea.gage import spans

    lo, hi = np.zeros(3), np.array([30.0, 10.0, 3.0])
    plain = parse_load_case(BAR, "part.load.toml")
    named = parse_load_case("[test]\ngage_length_mm = 10\nreads = 'stiffness'\n" + BAR)
    assert (named.gage_length_mm, named.reads) == (10.0, "stiffness")
    assert named.key() != plain.key()  # the optimum reads the named gage
    assert spans(plain, lo, hi) == (20.0, 30.0)  # the paper's 20 mm; the whole free length
    assert spans(named, lo, hi) == (10.0, 25.0, 30.0)


@pytest.mark.parametrize("name", sorted(PARSE_ERRORS))
def test_each_malformed_case_is_refused_with_its_own_reason(name: str) -> None:
    text, words = PARSE_ERRORS[name]
    with pytest.raises(LoadCaseError) as caught:
        parse_load_case(text, "part.load.toml")
    assert str(caught.value).startswith("part.load.toml: ")
    assert words in str(caught.value)


def test_a_region_that_selects_no_face_is_named_with_the_model_extent() -> None:
    bar = bar_mesh()
    case = parse_load_case(BAR.replace("[[30, 0, 0], [30, 10, 3]]", "[[40, 0, 0], [41, 10, 3]]"))
    with pytest.raises(LoadCaseError, match=r"\[\[force\]\] 1: box .* selects no face .*x 0..30"):
        analyse_arrays(bar.vertices, bar.faces, case)


def test_a_normal_filter_keeps_only_faces_facing_it() -> None:
    bar = bar_mesh()
    facing_away = BAR.replace("newtons = [100, 0, 0]", "newtons = [100, 0, 0]\nnormal = [-1, 0, 0]")
    with pytest.raises(LoadCaseError, match="selects no face of the model facing its normal"):
        analyse_arrays(bar.vertices, bar.faces, parse_load_case(facing_away))
    facing = BAR.replace("newtons = [100, 0, 0]", "newtons = [100, 0, 0]\nnormal = [1, 0.2, 0]")
    assert analyse_arrays(bar.vertices, bar.faces, parse_load_case(facing)).von_mises.max() > 0


def test_a_second_body_held_by_nothing_is_named_with_its_free_motion() -> None:
    two = trimesh.util.concatenate([bar_mesh(), bar_mesh().apply_translation([0, 20, 0])])
    with pytest.raises(LoadCaseError, match=r"body 2 of 2 \(.*y 20.*\) is held by no \[\[fixed\]\]"
                                            r" region: it is free to move along x, y and z"):
        analyse_arrays(two.vertices, two.faces, parse_load_case(BAR), size=1.0)


def test_pressure_pushes_into_the_part() -> None:
    bar = bar_mesh()
    text = BAR.split("[[force]]")[0] + "[[pressure]]\nbox = [[30, 0, 0], [30, 10, 3]]\nmpa = 2\n"
    solution = analyse_arrays(bar.vertices, bar.faces, parse_load_case(text), size=1.0)
    middle = np.abs(solution.mesh.centres[:, 0] - 15) < 3
    assert np.mean(solution.stress[middle, 0]) == pytest.approx(-2.0, rel=0.02)  # compression


def test_check_case_refuses_a_load_file_whose_model_is_missing(tmp_path: Path) -> None:
    load = tmp_path / "part.load.toml"
    load.write_text(BAR)
    with pytest.raises(LoadCaseError, match=r"part\.load\.toml: its model part\.stl is missing"):
        check_case(tmp_path / "part.stl", load)


def test_a_check_begun_while_the_files_settle_counts_only_for_the_same_files(
    tmp_path: Path,
) -> None:
    stl, load = tmp_path / "bar.stl", tmp_path / "bar.load.toml"
    bar_mesh().export(stl)
    load.write_text(BAR)
    no_face = BAR.replace("[[30, 0, 0], [30, 10, 3]]", "[[50, 0, 0], [51, 10, 3]]")

    async def scenario() -> list[str | None]:
        checks = LoadChecks(tmp_path / "fea")
        checks.begin(stl, load, {})
        good = await checks.refusal(stl, load, {})
        checks.begin(stl, load, {})
        load.write_text(no_face)  # the case changed after its check began
        changed = await checks.refusal(stl, load, {})
        checks.begin(stl, load, {})
        again = await checks.refusal(stl, load, {})
        return [good, changed, again]

    good, changed, again = asyncio.run(scenario())
    assert good is None
    assert changed is not None
    assert "selects no face" in changed
    assert again == changed


DAEMON_CASES = {
    "no_face": (BAR.replace("[[30, 0, 0], [30, 10, 3]]", "[[50, 0, 0], [51, 10, 3]]"),
                "selects no face"),
    "nothing_fixed": (BAR.split("[[force]]")[1].join(["[[force]]", ""]), "nothing is fixed"),
    "zero_load": (BAR.replace("[100, 0, 0]", "[0, 0, 0]"), "newtons is zero"),
    "unknown_key": (BAR.replace("box = [[0, 0, 0]", "bx = [[0, 0, 0]"), "unknown key 'bx'"),
}


def test_daemon_fails_bad_load_cases_with_their_reasons_and_prints_a_good_one(daemon, tmp_path):
    hostd = daemon(sim_config(time_scale=0.0))
    stl = tmp_path / "bar.stl"
    bar_mesh().export(stl)
    for stem, (text, _words) in DAEMON_CASES.items():
        hostd.drop(text.encode(), f"{stem}.load.toml")
        hostd.drop(stl, f"{stem}.stl")
    hostd.drop(BAR.encode(), "lonely.load.toml")
    hostd.drop(b"fea.mesh_size = 1.0\n", "good.toml")
    hostd.drop(BAR.encode(), "good.load.toml")
    hostd.drop(stl, "good.stl")
    failed, done = hostd.jobs / "failed", hostd.jobs / "done"
    expected = len(DAEMON_CASES) + 1
    hostd.wait_for(lambda: len(list(failed.glob("*.error.txt"))) >= expected, 60, "the failures")
    for stem, (_text, words) in DAEMON_CASES.items():
        reason = (failed / f"{stem}.error.txt").read_text()
        assert f"{stem}.load.toml: " in reason, reason
        assert words in reason, reason
        assert (failed / f"{stem}.stl").exists()
        assert (failed / f"{stem}.load.toml").exists()
    lonely = (failed / "lonely.load.error.txt").read_text()
    assert "lonely.load.toml: its model lonely.stl is missing" in lonely
    hostd.wait_for(lambda: (done / "good.summary.txt").exists(), 120, "the good job")
    summary = (done / "good.summary.txt").read_text()
    assert "stress analysis:" in summary
    assert "peak von Mises" in summary
    assert (done / "good.load.toml").exists()
    assert list((hostd.state / "fea").glob("stress-*.npz"))
