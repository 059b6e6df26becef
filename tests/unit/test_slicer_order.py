"""Bulk G-code formatting, travel checks and infill ordering match one-at-a-time versions."""

import numpy as np
import shapely

from slicer.fields.linear import hatch, hatch_many, line_frame
from slicer.output.gcode import _travels_leave, format_moves
from slicer.paths import order


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


def test_format_moves_writes_every_whole_part_and_fraction():
    """Every entry of the word tables (built by digit arithmetic) in use: all whole parts
    -999..999 with and without a sign, every 3- and 5-digit fraction's digits."""
    units = np.tile(np.arange(-999_999, 1_000_000, 997), 2)  # thousandths
    k = np.arange(len(units) // 2)
    e_units = np.concatenate([k * 99_991, k * 1_234_567]) % 100_000_000  # 10**-5 mm
    assert len({(u < 0, abs(u) // 1000) for u in units.tolist()}) == 2000  # "-0" too
    assert len(set((np.abs(units) % 1000).tolist())) == 1000
    for digits in (e_units // 100_000, e_units // 100 % 1000, e_units % 100):
        assert len(set(digits.tolist())) == int(digits.max()) + 1  # every one
    xy = np.column_stack([units / 1000.0, units[::-1] / 1000.0])
    e = e_units / 100_000.0
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


def test_islands_hatched_stacked_and_joined_at_once_match_one_at_a_time():
    # side by side, so the islands' chords line up level by level: batched, they must
    # still never share a zigzag stack or a joint
    islands = np.array([
        shapely.box(0, 0, 10, 10),
        shapely.box(10.5, 0, 20, 10).difference(shapely.box(13, 3, 16, 6)),
        shapely.Point(26, 5).buffer(4),
        None,
    ], dtype=object)
    g, d = line_frame(45.0, True)
    chords, owner = hatch_many(islands, 45.0, True, 0.4)
    stacks = order.chord_stacks(chords, owner, len(islands), g, d, 0.4)
    pos = np.array([0.0, 10.0])
    runs, want = [], []
    for k, island in enumerate(islands[:3]):
        alone = hatch(island, 45.0, True, 0.4)
        np.testing.assert_array_equal(chords[owner == k], alone)
        block, end = order.walk_stacks(stacks, k, pos)
        ordered, want_end = order.order_chords(alone, g, d, 0.4, pos)
        np.testing.assert_array_equal(block, np.array(ordered))
        np.testing.assert_array_equal(end, want_end)
        region = island.buffer(0)  # each join check prepares its own copy
        want.append(order.join_paths(ordered, region, 0.8, 0.2))
        runs.append((block.reshape(-1, 2), np.arange(2, 2 * len(block) + 1, 2), k))
        pos = end
    assert order.walk_stacks(stacks, 3, pos)[0].shape == (0, 2, 2)
    regions = np.array([i.buffer(0) for i in islands[:3]], dtype=object)
    got = order.join_runs(runs, regions, 0.8, 0.2)
    assert [len(r) for r in got] == [len(r) for r in want]
    for got_run, want_run in zip(got, want, strict=True):
        for a, b in zip(got_run, want_run, strict=True):
            np.testing.assert_array_equal(a, b)


def test_islands_ordered_alike_from_a_table_and_step_by_step(monkeypatch):
    """Nearest rear seam first, the same order whether the distances come from one table
    or one norm per step (ties and empty islands' NaN bounds included)."""
    from slicer.paths import layer

    rng = np.random.default_rng(11)
    lo = rng.integers(0, 40, (300, 2)).astype(float)  # many equal seams: ties
    box = np.column_stack([lo, lo + rng.integers(1, 5, (300, 2))])
    box[[5, 77]] = np.nan  # empty islands
    pos = layer._start_position(box)
    step_by_step = layer._island_order(box, pos)
    monkeypatch.setattr(layer, "_TABLE_ISLANDS", 1000)
    assert layer._island_order(box, pos) == step_by_step
    assert sorted(step_by_step) == list(range(300))
