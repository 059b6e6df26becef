"""The benchmark's G-code reading: filament, layers and outer-wall IoU on small generated G-code."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bench import gcodeparse as g

E_PER_MM = 0.03


def loop(
    x0: float, y0: float, size: float, z: float, kind: str = "WALL-OUTER",
    e_start: float | None = None, gap: float = 0.0,
) -> list[str]:
    """A square loop at height z, relative E unless ``e_start`` gives absolute E."""
    corners = [(x0 + size, y0), (x0 + size, y0 + size), (x0, y0 + size), (x0, y0 + gap)]
    lines = [f"G0 X{x0} Y{y0} Z{z}", f";TYPE:{kind}"]
    e = e_start
    prev = (x0, y0)
    for cx, cy in corners:
        step = float(np.hypot(cx - prev[0], cy - prev[1])) * E_PER_MM
        if e is None:
            lines.append(f"G1 X{cx} Y{cy} E{step:.5f}")
        else:
            e += step
            lines.append(f"G1 X{cx} Y{cy} E{e:.5f}")
        prev = (cx, cy)
    return lines


def test_relative_extrusion_counts_only_extruding_moves() -> None:
    lines = ["M83", *loop(0, 0, 10, 0.2), "G1 E-1.0 F2400", "G1 Z0.6", "G1 E1.0",
             *loop(0, 0, 10, 0.4)]
    moves = g.parse_moves(lines)
    st = g.stats(moves)
    assert st.filament_mm == pytest.approx(2 * 40 * E_PER_MM, rel=1e-6)
    assert st.layers == 2  # the hop to 0.6 lays nothing


def test_absolute_extrusion_with_g92_resets() -> None:
    lines = ["M82", "G92 E0", *loop(0, 0, 10, 0.2, e_start=0.0), "G92 E0",
             *loop(0, 0, 5, 0.4, e_start=0.0), "G92 E5", "G1 X3 Y3 E5.3"]
    st = g.stats(g.parse_moves(lines))
    assert st.filament_mm == pytest.approx(40 * E_PER_MM + 20 * E_PER_MM + 0.3, rel=1e-6)
    assert st.layers == 2


def test_line_numbers_checksums_and_feed_only_lines_are_ignored() -> None:
    lines = ["N1 M83*17", "N2 G1 X1 Y0 Z0.2 E0.5*99", "N3 G1 F1200*5", "G1 X2 Y0 E0.5 ; note"]
    moves = g.parse_moves(lines)
    assert moves.de.tolist() == [0.5, 0.5]
    assert moves.x0.tolist() == [0.0, 1.0]
    assert g.stats(moves).filament_mm == pytest.approx(1.0)


def test_relative_positioning_g91() -> None:
    moves = g.parse_moves(["G90", "G1 X10 Y10 Z1", "G91", "G1 X5 Y-2 E1", "G90", "G1 X0"])
    assert moves.x.tolist() == [10.0, 15.0, 0.0]
    assert moves.y.tolist() == [10.0, 8.0, 8.0]
    assert moves.de.tolist() == [0.0, 1.0, 0.0]


def test_outer_wall_region_is_even_odd_so_holes_stay_holes() -> None:
    lines = ["M83", *loop(0, 0, 20, 0.2), *loop(5, 5, 10, 0.2),
             *loop(1, 1, 18, 0.2, kind="WALL-INNER")]
    regions = g.outer_wall_regions(g.parse_moves(lines))
    assert list(regions) == [20]
    assert regions[20].area == pytest.approx(400 - 100)


def test_open_walls_are_left_out_and_nearly_closed_loops_kept() -> None:
    moves = g.parse_moves(["M83", *loop(0, 0, 10, 0.2, gap=0.1), *loop(0, 0, 10, 0.4, gap=5.0)])
    regions = g.outer_wall_regions(moves, close_tol=1.0)
    assert list(regions) == [20]
    assert regions[20].area == pytest.approx(100.0)


def test_overhang_stretch_continues_an_outer_loop() -> None:
    lines = ["M83", "G0 X0 Y0 Z0.2", ";TYPE:External perimeter", "G1 X10 Y0 E0.3",
             ";TYPE:Overhang perimeter", "G1 F3600", "G1 X10 Y10 E0.3",
             ";TYPE:External perimeter", "G1 F1800", "G1 X0 Y10 E0.3", "G1 X0 Y0 E0.3"]
    regions = g.outer_wall_regions(g.parse_moves(lines))
    assert regions[20].area == pytest.approx(100.0)


def test_overhang_only_loops_count_as_island_outlines_but_not_as_inner_perimeters() -> None:
    island = [*loop(30, 30, 10, 0.2, kind="Overhang perimeter"),  # island printed over air
              *loop(31, 31, 8, 0.2, kind="Overhang perimeter")]  # ... and its inner wall
    lines = ["M83", *loop(0, 0, 10, 0.2, kind="External perimeter"),
             *loop(1, 1, 8, 0.2, kind="Overhang perimeter"),  # inner perimeter over air
             *island]
    regions = g.outer_wall_regions(g.parse_moves(lines))
    assert regions[20].area == pytest.approx(100.0 + 100.0)
    only_island = g.outer_wall_regions(g.parse_moves(["M83", *island]))
    assert only_island[20].area == pytest.approx(100.0)


def test_iou_of_shifted_squares_and_alignment() -> None:
    a = g.parse_moves(["M83", *loop(0, 0, 10, 0.2), *loop(0, 0, 10, 0.4)])
    b = g.parse_moves(["M83", *loop(1, 0, 10, 0.2), *loop(1, 0, 10, 0.4)])
    raw = g.wall_agreement(a, b, align=False)
    assert raw.mean_iou == pytest.approx(90 / 110)
    aligned = g.wall_agreement(a, b, align=True)
    assert aligned.mean_iou == pytest.approx(1.0)
    assert aligned.offset == pytest.approx((1.0, 0.0))


def test_layer_missing_in_one_file_counts_as_zero() -> None:
    a = g.parse_moves(["M83", *loop(0, 0, 10, 0.2), *loop(0, 0, 10, 0.4)])
    b = g.parse_moves(["M83", *loop(0, 0, 10, 0.4)])
    agreement = g.wall_agreement(a, b, align=False)
    assert agreement.layers_a == 2
    assert agreement.layers_b == 1
    assert agreement.mean_iou == pytest.approx(0.5)
    assert agreement.mean_iou_common == pytest.approx(1.0)


def test_a_dot_smaller_than_one_line_square_is_no_outer_wall() -> None:
    # a slicer that ends a pointed mesh with a 0.1 mm loop prints a dot, not an outline
    a = g.parse_moves(["M83", *loop(0, 0, 10, 0.2), *loop(0, 0, 0.1, 0.4)])
    b = g.parse_moves(["M83", *loop(0, 0, 10, 0.2)])
    assert list(g.outer_wall_regions(a)) == [20]
    assert g.outer_wall_regions(a, min_area=0.0)[40].area == pytest.approx(0.01)
    assert g.wall_agreement(a, b, align=False).mean_iou == pytest.approx(1.0)


def test_read_moves_from_file(tmp_path: Path) -> None:
    path = tmp_path / "t.gcode"
    path.write_text("\n".join(["M83", *loop(0, 0, 10, 0.2)]) + "\n")
    moves = g.read_moves(path)
    assert moves.types == ("WALL-OUTER",)
    assert int(moves.extruding.sum()) == 4


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("G1 X1 Y2 E0.5", True),
        ("N12 G1 X1 E0.02*33", True),
        ("G1 X-1 E.3", True),
        ("G1 E2", False),  # priming in place
        ("G1 X1 Y1 E-0.8", False),  # retracting while wiping
        ("G1 X1 Y1 E0", False),
        ("G0 X1 Y1", False),
        ("G1 X1.0 Y1 F1200 ; E5", False),  # E only in the comment
        ("G1 Z0.2 E1", False),
        ("M104 S200", False),
    ],
)
def test_first_extrusion_detection(line: str, expected: bool) -> None:
    assert g.is_extruding_line(line) is expected


def test_worst_layers_are_listed_by_height() -> None:
    a = g.parse_moves(["M83", *loop(0, 0, 10, 0.2), *loop(0, 0, 10, 0.4)])
    b = g.parse_moves(["M83", *loop(0, 0, 10, 0.2), *loop(5, 0, 10, 0.4)])
    agreement = g.wall_agreement(a, b, align=False)
    worst = agreement.worst(1)
    assert worst[0][0] == pytest.approx(0.4)
    assert worst[0][1] == pytest.approx(50 / 150)
    assert len(agreement.per_layer) == 2


def test_arcs_are_read_as_chords_on_their_circle() -> None:
    lines = ["G90", "M83", "G0 X20 Y10", "G2 X20 Y10 I-10 J0 E3", "G3 X10 Y0 I-10 J0 E1.5"]
    moves = g.parse_moves(lines)
    arcs = slice(1, None)
    r = np.hypot(moves.x[arcs] - 10.0, moves.y[arcs] - 10.0)
    assert np.allclose(r, 10.0)
    # a full turn, then three quarters of one
    assert moves.xy_length[arcs].sum() == pytest.approx(3.5 * np.pi * 10.0, rel=1e-3)
    assert moves.de.sum() == pytest.approx(4.5)
    assert (moves.x[-1], moves.y[-1]) == (10.0, 0.0)
    assert g.stats(moves).moves == 3
    assert g.is_extruding_line("G2 X20 Y10 I-10 J0 E3")
