"""Bulk G-code formatting and travel checks give what the one-at-a-time versions give."""

import numpy as np
import shapely

from slicer.gcode import _travels_leave, format_moves


def _python_lines(xy: np.ndarray, e: np.ndarray) -> list[str]:
    rows = zip(xy.tolist(), e.tolist(), strict=True)
    return [f"G1 X{x:.3f} Y{y:.3f} E{v:.5f}" for (x, y), v in rows]


def _python_travels(xy: np.ndarray) -> list[str]:
    return [f"G0 F9000 X{x:.3f} Y{y:.3f}" for x, y in xy.tolist()]


def test_format_moves_matches_python_formatting():
    rng = np.random.default_rng(7)
    m = 20000
    xy = rng.uniform(-999.9, 999.9, (m, 2)) * rng.choice([1.0, 1e-3, 1e-4], (m, 2))
    e = rng.uniform(0.0, 20.0, m) * rng.choice([1.0, 1e-4, 1e-5], m)
    # values whose scaled product lies at or next to half a unit
    xy[:100] = np.round(xy[:100], 3) + 0.0005
    e[:100] = np.round(e[:100], 5) + 0.000005
    xy[100:110, 0] = [0.0625, -0.0625, 1.0625, 0.0005, -0.0005, -0.0, 0.0, 999.9994, 2.5e-4, -1e-9]
    e[100:104] = [0.0, 0.000005, 0.0000125, 999.99999]
    # exact binary ties: odd sixteenths are half a thousandth, odd 64ths half of 10**-5
    xy[200:1200] = rng.integers(-15000, 15000, (1000, 2)) * 2 + 1
    xy[200:1200] /= 16.0
    e[200:1200] = (rng.integers(0, 20000, 1000) * 2 + 1) / 64.0
    assert format_moves("G1 ", xy, e) == _python_lines(xy, e)
    assert format_moves("G0 F9000 ", xy) == _python_travels(xy)


def test_format_moves_falls_back_outside_three_whole_digits():
    for bad in (1000.0, 999.9996, -1234.5, np.nan, np.inf):
        xy = np.array([[bad, 1.0], [2.0, 3.0]])
        e = np.array([0.1, 0.2])
        assert format_moves("G1 ", xy, e) == _python_lines(xy, e)
        assert format_moves("G0 F9000 ", xy) == _python_travels(xy)
    assert format_moves("G1 ", np.zeros((0, 2)), np.zeros(0)) == []


def test_travels_leave_matches_covered_by():
    part = shapely.Polygon(
        [(0, 0), (20, 0), (20, 20), (0, 20)], holes=[[(5, 5), (15, 5), (15, 15), (5, 15)]]
    )
    outline = shapely.union(part, shapely.box(30, 0, 40, 10))
    rng = np.random.default_rng(3)
    a = rng.uniform(-2.0, 42.0, (500, 2))
    b = rng.uniform(-2.0, 42.0, (500, 2))
    # along an edge, touching a hole's corner, zero length
    a[:3] = [(0, 0), (4, 4), (1, 1)]
    b[:3] = [(20, 0), (6, 6), (1, 1)]
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    expected = ~(shapely.covered_by(lines, outline) | np.all(a == b, axis=1))
    assert (_travels_leave(a, b, outline, 0.4) == expected).all()
    assert not _travels_leave(a[:1], b[:1], outline, 0.4)[0]
