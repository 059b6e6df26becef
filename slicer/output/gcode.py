"""Marlin G-code: one layer's toolpaths to lines, start/end blocks, header and summary.

Extrusion is relative (``M83``): every layer starts by retracting, moving to
its height and priming, so a layer's lines depend on that layer alone.
E per move is by volume: length x line width x layer height / filament area.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import NDArray

from slicer.geometry.geom import private_copy
from slicer.output.budget import Moves, budget_moves, line_rate
from slicer.output.layertime import layer_time
from slicer.output.motion import run_time, segment_times
from slicer.paths.arcs import arcs_wanted
from slicer.paths.detour import detours
from slicer.paths.layer import FILL, SUPPORT, WALL_OUTER, Path
from slicer.settings import SliceSettings

# points of a path closer than this to the previous one are dropped, mm
_MIN_STEP = 0.005
# layers are made together up to about this many path points (beyond, a pass's
# arrays outgrow the caches and a bigger pass gains nothing)
BATCH_POINTS = 20_000
# lift used when a print ends or resumes, mm
END_LIFT = 10.0
RESUME_LIFT = 0.6
# shapely type ids of the part outlines
_POLYGON, _MULTIPOLYGON = 3, 6


@dataclass(frozen=True)
class GcodeSummary:
    """Totals of a G-code program: layers, filament length (mm) and mass (g), time (s)."""

    layers: int
    filament_mm: float
    filament_g: float
    time_s: float


@dataclass(frozen=True)
class LayerCode:
    """One layer's G-code lines with its filament use (mm) and estimated time (s).

    ``z_line`` is the index in ``lines`` of the travel that moves to the
    layer's height (0 when the layer prints nothing): with ``lines[0]``
    (``;LAYER:i``) the only lines that name the layer's number or height.
    ``spans``, when asked for, says which lines each path's moves are and whose:
    (m, 3) int64 rows (first line, last line, owner), one per path with moves,
    in print order, the owner as given per path (a body; see
    :meth:`slicer.output.labels.ObjectLabels.label_layer`). None when not asked for.
    """

    lines: list[str]
    filament_mm: float
    time_s: float
    z_line: int = 0
    spans: np.ndarray | None = None

    def moved_to(self, index: int, z: float) -> LayerCode:
        """These lines as layer ``index`` at top height ``z`` mm (same paths and speeds)."""
        lines = list(self.lines)
        lines[0] = f";LAYER:{index}"
        if self.z_line:
            head, _, _ = lines[self.z_line].rpartition(" Z")
            lines[self.z_line] = f"{head} Z{z:.3f}"
        return LayerCode(lines, self.filament_mm, self.time_s, self.z_line, self.spans)


def _island_scale(
    outline: shapely.Geometry, first: np.ndarray, exact: np.ndarray
) -> np.ndarray | None:
    """Per path, area over boundary length (mm) of the island of ``outline`` nearest its
    first point ``first`` ((n, 2) mm) where ``exact``, inf elsewhere; None without islands."""
    islands = shapely.get_parts(outline) if outline is not None else np.zeros(0, dtype=object)
    islands = islands[shapely.area(islands) > 0] if len(islands) else islands
    if len(islands) == 0 or not exact.any():
        return None
    scale = np.full(len(first), np.inf)
    tree = shapely.STRtree(islands)
    rows = np.flatnonzero(exact)
    hit = tree.query_nearest(shapely.points(first[rows]), all_matches=False)
    island = np.empty(len(rows), dtype=np.int64)
    island[hit[0]] = hit[1]
    per_island = shapely.area(islands) / shapely.length(islands)
    scale[rows] = per_island[island]
    return scale


def fan_command(settings: SliceSettings, index: int) -> str:
    """The fan command that holds from layer ``index`` on (``M106 S..`` or ``M107``)."""
    if index >= settings.fan_first_layer and settings.fan_speed > 0:
        return f"M106 S{round(255 * settings.fan_speed)}"
    return "M107"


@dataclass(frozen=True)
class LayerJob:
    """What one layer's G-code is made from (the arguments of :func:`layer_code`)."""

    index: int
    z: float
    height: float
    paths: Sequence[Path]
    outline: shapely.Geometry
    avoid: shapely.Geometry | None = None
    owners: np.ndarray | Sequence[int] | None = None


def layer_code(
    index: int,
    z: float,
    height: float,
    paths: Sequence[Path],
    outline: shapely.Geometry,
    settings: SliceSettings,
    avoid: shapely.Geometry | None = None,
    owners: np.ndarray | Sequence[int] | None = None,
) -> LayerCode:
    """G-code of one layer: ``;LAYER:index``, then every path with travels between.

    ``z`` is the layer's top (nozzle height), ``height`` its thickness, both mm;
    ``outline`` the layer's solid region: a travel that leaves it retracts; a travel
    that would cross ``avoid`` (a cancelled body's region) goes around it, retracted.
    All extrusion moves of the layer are measured and formatted in one
    vectorised pass; only the few lines between paths are built per path.
    With ``owners`` (one number per path: its body) the result carries each path's
    lines and owner (:attr:`LayerCode.spans`).
    """
    job = LayerJob(index, z, height, paths, outline, avoid, owners)
    return layer_codes([job], settings)[0]


def layer_codes(jobs: Sequence[LayerJob], settings: SliceSettings) -> list[LayerCode]:
    """:func:`layer_code` of every job, the same bytes as one by one, in fewer passes.

    The moves of all the layers are packed, simplified, measured, formatted and
    tested against their outlines together (every step is done path by path or
    move by move, so a layer's results do not depend on the others); what runs
    along a layer's whole chain of moves (its time, the wire's budget, arcs'
    island scale) is done layer by layer.
    """
    codes = [LayerCode([f";LAYER:{job.index}"], 0.0, 0.0) for job in jobs]
    group: list[int] = []
    points = 0
    for k, job in enumerate(jobs):
        if not job.paths:
            continue
        size = sum(len(p.coords) for p in job.paths)
        if group and points + size > BATCH_POINTS:
            _made_together([jobs[j] for j in group], settings, group, codes)
            group, points = [], 0
        group.append(k)
        points += size
    if group:
        _made_together([jobs[j] for j in group], settings, group, codes)
    return codes


def _made_together(
    layers: Sequence[LayerJob], settings: SliceSettings, slots: Sequence[int],
    codes: list[LayerCode],
) -> None:
    """:func:`layer_codes` of ``layers`` (each with paths), put in ``codes[slots[k]]``."""
    paths = [p for job in layers for p in job.paths]
    counts = np.array([len(job.paths) for job in layers])
    path_layer = np.repeat(np.arange(len(layers)), counts)
    first_path = np.cumsum(counts) - counts
    first_layer = np.array([job.index == 0 for job in layers])
    wall_f = np.where(first_layer, settings.first_layer_speed, settings.wall_speed)
    fill_f = np.where(first_layer, settings.first_layer_speed, settings.print_speed)
    is_wall = np.array([p.kind.startswith("WALL") for p in paths])
    speeds = np.where(is_wall, wall_f[path_layer], fill_f[path_layer])
    widths = np.array([settings.line_width if p.width is None else p.width for p in paths])
    # the emitted moves: simplified within the resolution, arcs where they fit
    loose = np.array([p.kind in (FILL, SUPPORT) for p in paths])
    exact = np.array([p.kind == WALL_OUTER for p in paths])
    pts, starts, ends = _pack([p.coords for p in paths])
    mv = _budgeted(layers, pts, starts, ends, first_path, counts, speeds, loose, exact,
                   settings)
    # extrusion moves: every point but each path's first
    sizes = mv.ends - mv.starts
    move = np.ones(len(mv.pts), dtype=bool)
    move[mv.starts] = False
    e_per_mm = np.array([job.height for job in layers]) / settings.filament_area
    e = mv.length * np.repeat(e_per_mm[path_layer], sizes) * np.repeat(widths, sizes)
    e_moves = e[move]
    g1 = _format_layer_moves(mv, move, e)
    # each path's moves in g1: [first_move, last_move); each layer's: [move_lo, move_hi)
    last_move = np.cumsum(sizes - 1)
    first_move = last_move - (sizes - 1)
    move_hi = last_move[first_path + counts - 1]
    move_lo = first_move[first_path]

    # the travel before each path but a layer's first
    inner = path_layer[1:] == path_layer[:-1]
    travel_a = pts[ends[:-1] - 1][inner]
    travel_b = pts[starts[1:]][inner]
    travel_layer = path_layer[1:][inner]
    leaves = _travels_leave_many(travel_a, travel_b, travel_layer,
                                 [job.outline for job in layers], settings.line_width)
    first_travel = first_path - np.arange(len(layers))  # of each layer, in the travels
    travel_f = settings.travel_speed
    r = settings.retract_length
    retract = f"G1 E{-r:.5f} F{_fpm(settings.retract_speed)}" if r > 0 else ""
    prime = f"G1 E{r:.5f} F{_fpm(settings.retract_speed)}" if r > 0 else ""
    travels = format_moves(f"G0 F{_fpm(travel_f)} ", travel_b)
    # plain Python values for the per-path loop (numpy scalars are slow to index)
    feed_of = {v: _fpm(v) for v in set(speeds.tolist())}
    feeds = [feed_of[v] for v in speeds.tolist()]
    firsts, lasts = first_move.tolist(), last_move.tolist()
    kinds = [p.kind for p in paths]
    for slot, (job, p0, n) in enumerate(zip(layers, first_path.tolist(), counts.tolist(),
                                            strict=True)):
        t0 = int(first_travel[slot])
        a, b = travel_a[t0 : t0 + n - 1], travel_b[t0 : t0 + n - 1]
        hops_l = leaves[t0 : t0 + n - 1]
        via = _detours(a, b, job.avoid, travel_f, settings.acceleration)
        if via:
            hops_l = hops_l.copy()
            hops_l[list(via)] = True
        moves_l = _layer_moves(mv, p0, n)
        time_s = layer_time(moves_l, speeds[p0 : p0 + n], travel_f, hops_l, r,
                            settings.retract_speed, job.height, settings.acceleration)
        time_s += sum(extra for _, extra in via.values())
        filament = float(e_moves[move_lo[slot] : move_hi[slot]].sum())
        lines = [f";LAYER:{job.index}"]
        if job.index == settings.fan_first_layer or (
                job.index == 0 and settings.fan_first_layer > 0):
            lines.append(fan_command(settings, job.index))
        if retract:
            lines.append(retract)
        x0, y0 = pts[starts[p0]]
        z_line = len(lines)
        lines.append(f"G0 F{_fpm(travel_f)} X{x0:.3f} Y{y0:.3f} Z{job.z:.3f}")
        if prime:
            lines.append(prime)
        kind = None
        hops = hops_l.tolist()
        moves_at = [0] * n  # where each path's first move went in ``lines``
        for j in range(n):
            k = p0 + j
            if j > 0:
                hop = hops[j - 1] and retract
                if hop:
                    lines.append(retract)
                if via and j - 1 in via:
                    lines.extend(via[j - 1][0])
                lines.append(travels[t0 + j - 1])
                if hop:
                    lines.append(prime)
            if kinds[k] != kind:
                kind = kinds[k]
                lines.append(f";TYPE:{kind}")
            lo, hi = firsts[k], lasts[k]
            moves_at[j] = len(lines)
            if hi > lo:
                lines.append(f"{g1[lo][:3]}F{feeds[k]} {g1[lo][3:]}")
                lines.extend(g1[lo + 1 : hi])
        spans = None
        if job.owners is not None:
            count = (last_move - first_move)[p0 : p0 + n]
            has = count > 0
            first_line = np.asarray(moves_at, dtype=np.int64)[has]
            spans = np.column_stack([first_line, first_line + count[has] - 1,
                                     np.asarray(job.owners, dtype=np.int64)[has]])
        codes[slots[slot]] = LayerCode(lines, filament, time_s, z_line, spans)


def _budgeted(
    layers: Sequence[LayerJob], pts: np.ndarray, starts: np.ndarray, ends: np.ndarray,
    first_path: np.ndarray, counts: np.ndarray, speeds: np.ndarray, loose: np.ndarray,
    exact: np.ndarray, settings: SliceSettings,
) -> Moves:
    """The moves of every layer's packed paths (:func:`slicer.output.budget.budget_moves`):
    in one pass, or layer by layer where the budget looks along a layer's chain of
    moves (arcs bounded by the islands' scale, the wire's rate)."""
    arcs = arcs_wanted(settings)
    if not (arcs or line_rate(settings) > 0):
        return budget_moves(pts, starts, ends, speeds, settings, loose, exact)
    parts = []
    for job, p0, n in zip(layers, first_path.tolist(), counts.tolist(), strict=True):
        lo, hi = int(starts[p0]), int(ends[p0 + n - 1])
        s, e = starts[p0 : p0 + n] - lo, ends[p0 : p0 + n] - lo
        own = slice(p0, p0 + n)
        # the islands' scale bounds outer walls' arcs only: no arcs, no need to find it
        scale = _island_scale(job.outline, pts[lo:hi][s], exact[own]) if arcs else None
        parts.append(budget_moves(pts[lo:hi], s, e, speeds[own], settings, loose[own],
                                  exact[own], scale))
    return _joined_moves(parts)


def _joined_moves(parts: Sequence[Moves]) -> Moves:
    """Layers' moves one after the other, as one :class:`~slicer.output.budget.Moves`."""
    if len(parts) == 1:
        return parts[0]
    base = np.cumsum([0] + [len(m.pts) for m in parts[:-1]])
    return Moves(
        np.concatenate([m.pts for m in parts]),
        np.concatenate([m.starts + b for m, b in zip(parts, base, strict=True)]),
        np.concatenate([m.ends + b for m, b in zip(parts, base, strict=True)]),
        np.concatenate([m.arc for m in parts]),
        np.concatenate([m.centre for m in parts]),
        np.concatenate([m.ccw for m in parts]),
        np.concatenate([m.length for m in parts]),
    )


def _layer_moves(mv: Moves, p0: int, n: int) -> Moves:
    """The moves of paths ``p0 .. p0 + n - 1`` of ``mv`` (one layer's) on their own."""
    lo, hi = int(mv.starts[p0]), int(mv.ends[p0 + n - 1])
    if lo == 0 and hi == len(mv.pts):
        return mv
    length = mv.length[lo:hi].copy()
    length[0] = 0.0  # as measured alone: nothing before the first point
    return Moves(mv.pts[lo:hi], mv.starts[p0 : p0 + n] - lo, mv.ends[p0 : p0 + n] - lo,
                 mv.arc[lo:hi], mv.centre[lo:hi], mv.ccw[lo:hi], length)


def _detours(
    a: np.ndarray, b: np.ndarray, avoid: shapely.Geometry | None, travel_f: float, accel: float
) -> dict[int, tuple[list[str], float]]:
    """The travels ``a[k] -> b[k]`` that go around ``avoid``: k -> (the moves before the
    travel's own line, the seconds the way round adds)."""
    out = {}
    for k, points in enumerate(detours(a, b, avoid)):
        if len(points):
            way = np.vstack([a[k], points, b[k]])
            extra = run_time(way, travel_f, accel) - run_time(way[[0, -1]], travel_f, accel)
            out[k] = (format_moves(f"G0 F{_fpm(travel_f)} ", points), extra)
    return out


def _format_layer_moves(mv: Moves, move: np.ndarray, e: np.ndarray) -> list[str]:
    """The lines of every move (points where ``move``): ``G1 X Y E``, or ``G2``/``G3`` (clockwise,
    counter-clockwise) ``X Y I J E`` for arcs, I and J from the move's start to the centre."""
    xy, ee, arc, ccw = mv.pts[move], e[move], mv.arc[move], mv.ccw[move]
    if not arc.any():
        return format_moves("G1 ", xy, ee)
    out = np.empty(len(xy), dtype=object)
    line = ~arc
    out[line] = format_moves("G1 ", xy[line], ee[line])
    before = np.flatnonzero(move) - 1  # each move starts at the point before it
    ij = mv.centre[move] - mv.pts[before]
    for head, sel in (("G2 ", arc & ~ccw), ("G3 ", arc & ccw)):
        if sel.any():
            out[sel] = format_moves(head, xy[sel], ee[sel], ij[sel])
    return out.tolist()


# Moves are formatted as bytes by table lookups (a Python ``%`` per number
# dominated a layer's time). Each number becomes fixed-size 4-byte words
# padded with NUL bytes, which are deleted from the finished text.
_WORD = np.dtype(np.uint32)


def _words(texts: list[str]) -> np.ndarray:
    """Each text (at most 4 ASCII characters) as one NUL-padded 4-byte word: (k,) uint32."""
    return np.frombuffer(b"".join(t.encode("ascii").ljust(4, b"\0") for t in texts), _WORD)


def _digit_words(count: int, places: int, lead: str = "", pad: bool = True) -> np.ndarray:
    """The words of ``lead + str(q)`` for q in ``0..count-1``, ``places`` digits each (zeros
    in front) when ``pad``, else as few as ``str`` writes: (count,) uint32, built by
    arithmetic on the digits (a Python string per number cost milliseconds at import)."""
    q = np.arange(count)
    digits = np.stack([q // 10**p % 10 for p in range(places - 1, -1, -1)], axis=1)
    shown = np.full(count, places)
    if not pad:
        shown = 1 + sum((q >= 10**p).astype(int) for p in range(1, places))
    out = np.zeros((count, 4), dtype=np.uint8)
    head = np.frombuffer(lead.encode("ascii"), dtype=np.uint8)
    out[:, : len(head)] = head
    for k in range(places):  # the k-th digit shown, where a number has one
        col = places - shown + k  # its column in ``digits``
        has = k < shown
        out[has, len(head) + k] = 48 + digits[has, col[has]]
    return out.view(_WORD).reshape(count)


# whole part with its sign: _WHOLE[1, q] is "-q"; digits after the point, 3 then 2
_WHOLE = np.stack([_digit_words(1000, 3, "", pad=False), _digit_words(1000, 3, "-", pad=False)])
_FRAC3 = _digit_words(1000, 3, ".")
_DIGITS2 = _digit_words(100, 2)
_SPACE_Y, _SPACE_E, _NEWLINE, _SPACE_I, _SPACE_J = _words([" Y", " E", "\n", " I", " J"])


def format_moves(
    head: str, xy: np.ndarray, e: np.ndarray | None = None, ij: np.ndarray | None = None
) -> list[str]:
    """The lines ``head + "X%.3f Y%.3f" % (x, y)``, with ``" I%.3f J%.3f" % (i, j)`` when
    ``ij`` is given and ``" E%.5f" % e`` when ``e`` is given, of many moves, byte for byte.

    ``head`` ASCII text (e.g. ``"G1 "``); ``xy`` and ``ij`` (m, 2) mm, ``e`` (m,) mm.
    Falls back to Python formatting when a value is not finite or has more than
    three whole digits once rounded.
    """
    if ij is not None:
        xy = np.column_stack([xy, ij])
    xy_units = _rounded(xy, 3)
    e_units = _rounded(e, 5) if e is not None else None
    if xy_units is None or (e is not None and e_units is None):
        template = (head + "X%.3f Y%.3f" + (" I%.3f J%.3f" if ij is not None else "")
                    + (" E%.5f" if e is not None else "") + "\n")
        columns = [xy] if e is None else [xy, e]
        flat = np.column_stack(columns).ravel().tolist()
        return ((template * len(xy)) % tuple(flat)).splitlines()
    text = head + "X"
    lead = _words([text[i : i + 4] for i in range(0, len(text), 4)])
    h = len(lead)
    # head, X and Y (whole and fraction each, " Y" between), I and J likewise,
    # E (" E" and three), newline
    h_e = h + 5 + (6 if ij is not None else 0)
    width = h_e + (4 if e is not None else 0) + 1
    words = np.empty((len(xy), width), dtype=_WORD)
    words[:, :h] = lead
    sign, units = xy_units
    words[:, h] = _WHOLE[sign[:, 0], units[:, 0] // 1000]
    words[:, h + 1] = _FRAC3[units[:, 0] % 1000]
    words[:, h + 2] = _SPACE_Y
    words[:, h + 3] = _WHOLE[sign[:, 1], units[:, 1] // 1000]
    words[:, h + 4] = _FRAC3[units[:, 1] % 1000]
    if ij is not None:
        words[:, h + 5] = _SPACE_I
        words[:, h + 6] = _WHOLE[sign[:, 2], units[:, 2] // 1000]
        words[:, h + 7] = _FRAC3[units[:, 2] % 1000]
        words[:, h + 8] = _SPACE_J
        words[:, h + 9] = _WHOLE[sign[:, 3], units[:, 3] // 1000]
        words[:, h + 10] = _FRAC3[units[:, 3] % 1000]
    if e_units is not None:
        sign, units = e_units
        words[:, h_e] = _SPACE_E
        words[:, h_e + 1] = _WHOLE[sign, units // 100000]
        words[:, h_e + 2] = _FRAC3[units % 100000 // 100]
        words[:, h_e + 3] = _DIGITS2[units % 100]
    words[:, -1] = _NEWLINE
    return words.tobytes().translate(None, b"\0").decode("ascii").splitlines()


def _rounded(v: np.ndarray, decimals: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Sign (1 where negative, -0.0 included) and ``abs(v)`` in units of ``10**-decimals``
    rounded exactly as ``"%.{decimals}f"`` rounds: two int64 arrays shaped as ``v``.

    ``%`` rounds the exact value of the double, ties to even. The float product
    ``abs(v) * 10**decimals`` is within half an ulp of the exact one, so ``rint``
    of it is right except where it lies near a half unit: those products are
    settled exactly by :func:`_round_near_half`. None when a value is not
    finite or has more than three whole digits.
    """
    scale = 10.0**decimals
    scaled = np.abs(v) * scale
    # also rules out NaN and infinities; rint of anything below stays below 1000
    if not (scaled < 1000 * scale - 0.5).all():
        return None
    units = np.rint(scaled)
    near = np.abs(scaled - np.floor(scaled) - 0.5) < 1e-6
    if near.any():
        units[near] = _round_near_half(np.abs(v[near]), scale)
    return np.signbit(v).astype(np.int64), units.astype(np.int64)


def _round_near_half(a: NDArray[np.float64], scale: float) -> NDArray[np.float64]:
    """``a * scale`` rounded to a whole number, ties to even, for products within
    1e-6 of a half: (k,) float64 whole numbers.

    The sign of ``a * scale - half`` is found exactly: ``a`` is split into a
    high part of 26 significant bits and the rest (Veltkamp's split), each
    times ``scale`` (a power of ten up to 10**11 has at most 26 significant
    bits) is exact, the high product minus the half is exact (the two are
    within a factor of two: Sterbenz), and one rounded addition keeps the
    sign of the exact sum (zero only when it is zero: a true tie).
    """
    low = np.floor(a * scale)
    split = a * 134217729.0  # 2**27 + 1
    high = split - (split - a)
    side = (high * scale - (low + 0.5)) + (a - high) * scale
    rounded: NDArray[np.float64] = low + ((side > 0) | ((side == 0) & (low % 2 == 1)))
    return rounded


def _fpm(speed_mm_s: float) -> int:
    """Feedrate word value: mm/min, whole."""
    return round(speed_mm_s * 60.0)


def _pack(paths: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate paths, dropping points closer than ``_MIN_STEP`` to the previous one.

    Returns points (m, 2) mm and each path's ``[start, end)`` indices (n,) into
    them. Every path keeps its two ends.
    """
    sizes = np.array([len(p) for p in paths])
    pts = np.concatenate(paths)
    path_of = np.repeat(np.arange(len(paths)), sizes)
    edge = np.zeros(len(pts), dtype=bool)
    edge[np.cumsum(sizes) - sizes] = True
    edge[np.cumsum(sizes) - 1] = True
    step = np.hypot(*np.diff(pts, axis=0, prepend=pts[:1]).T)
    keep = edge | (step >= _MIN_STEP)
    pts, path_of = pts[keep], path_of[keep]
    starts = np.searchsorted(path_of, np.arange(len(paths)), "left")
    ends = np.searchsorted(path_of, np.arange(len(paths)), "right")
    return pts, starts, ends


def _travels_leave(
    a: np.ndarray, b: np.ndarray, outline: shapely.Geometry, w: float
) -> NDArray[np.bool_]:
    """Which travels ``a[i] -> b[i]`` (each (n, 2) mm) leave the part (retraction needed)."""
    return _travels_leave_many(a, b, np.zeros(len(a), dtype=np.int64), [outline], w)


def _travels_leave_many(
    a: np.ndarray, b: np.ndarray, layer: np.ndarray, outlines: Sequence[shapely.Geometry],
    w: float,
) -> NDArray[np.bool_]:
    """Which travels ``a[i] -> b[i]`` (each (n, 2) mm) leave their layer's part
    ``outlines[layer[i]]`` (retraction needed).

    A travel that starts inside the part and meets none of its edges stays
    inside: two cheap indexed tests settle most travels, and only those that
    start off the interior or touch an edge are decided by ``covered_by``.
    """
    if len(a) == 0:
        return np.zeros(0, dtype=bool)
    lines = shapely.linestrings(np.stack([a, b], axis=1))
    zero = np.all(a == b, axis=1)
    # private, prepared copies: the outlines may be shared with other threads
    areas = np.empty(len(outlines), dtype=object)
    areas[:] = [private_copy(o) for o in outlines]
    shapely.prepare(areas)
    covered = np.zeros(len(a), dtype=bool)
    polygonal = np.isin(shapely.get_type_id(areas), (_POLYGON, _MULTIPOLYGON))
    tested = np.flatnonzero(polygonal[layer])
    if len(tested):
        edges = np.empty(len(outlines), dtype=object)
        edges[polygonal] = shapely.boundary(areas[polygonal])
        shapely.prepare(edges[polygonal])
        at = layer[tested]
        covered[tested] = (shapely.contains_xy(areas[at], a[tested, 0], a[tested, 1])
                           & ~shapely.intersects(edges[at], lines[tested]))
    rest = np.flatnonzero(~covered)
    covered[rest] = shapely.covered_by(lines[rest], areas[layer[rest]])
    leave: NDArray[np.bool_] = ~(covered | zero)
    return leave


def heat_commands(settings: SliceSettings) -> list[str]:
    """Set both heaters, then wait for bed and nozzle; nothing when ``skip_heating``."""
    if settings.skip_heating:
        return []
    return [
        f"M140 S{settings.bed_temp:g}",
        f"M104 S{settings.nozzle_temp:g}",
        f"M190 S{settings.bed_temp:g}",
        f"M109 S{settings.nozzle_temp:g}",
    ]


def start_block(settings: SliceSettings) -> list[str]:
    """Heat (unless ``skip_heating``), home, absolute XYZ, relative E."""
    lines = heat_commands(settings)
    # lift after homing so the travel to the first layer's start never drags on the bed
    lines += ["G28", "G90", "M83", "G92 E0", "G0 F600 Z5", fan_command(settings, 0)]
    return lines


def end_block(settings: SliceSettings, top_z: float, bed_z: float) -> list[str]:
    """Retract, lift clear of the part, heaters and fan off, motors off."""
    lift = min(top_z + END_LIFT, bed_z)
    lines = [";END"]
    if settings.retract_length > 0:
        lines.append(f"G1 E{-settings.retract_length:.5f} F{_fpm(settings.retract_speed)}")
    lines += [
        f"G0 F{_fpm(settings.travel_speed)} Z{lift:.3f}",
        "M107",
        "M104 S0",
        "M140 S0",
        "M84",
    ]
    return lines


def resume_block(settings: SliceSettings, index: int, below_z: float) -> list[str]:
    """The preamble that restarts a print at layer ``index``.

    ``below_z`` is the top of the last completed layer (0 for layer 0): the
    nozzle is there; declare that height, lift clear, heat (unless
    ``skip_heating``), home X and Y only, and restore relative E from zero.
    """
    lift = below_z + RESUME_LIFT
    lines = [f";RESUME:{index}", "G90", f"G92 Z{below_z:.3f}", f"G0 F600 Z{lift:.3f}"]
    lines += heat_commands(settings)
    lines += ["G28 X Y", "M83", "G92 E0", fan_command(settings, index)]
    return lines


def header_lines(summary: GcodeSummary, settings: SliceSettings) -> list[str]:
    """Comment header with totals in the forms Cura and PrusaSlicer viewers read."""
    t = round(summary.time_s)
    h, rem = divmod(t, 3600)
    m, s = divmod(rem, 60)
    return [
        ";FLAVOR:Marlin",
        ";Generated with hostd (implicit slicer)",
        f";TIME:{t}",
        f";Filament used: {summary.filament_mm / 1000.0:.5f}m",
        f";Filament mass: {summary.filament_g:.2f}g",
        f";Layer height: {settings.layer_height:g}",
        f";LAYER_COUNT:{summary.layers}",
        ";Extrusion: relative (M83)",
        f"; estimated printing time (normal mode) = {h}h {m}m {s}s",
        f"; filament used [mm] = {summary.filament_mm:.2f}",
        f"; filament used [g] = {summary.filament_g:.2f}",
        f"; infill = {settings.infill_field} {settings.infill_density:g}",
    ]


def filament_grams(filament_mm: float, settings: SliceSettings) -> float:
    """Mass of a length of filament, g (density in g/cm^3)."""
    return filament_mm * settings.filament_area * settings.filament_density / 1000.0


def summarize(lines: Iterable[str], settings: SliceSettings | None = None) -> GcodeSummary:
    """Totals of G-code lines: ``;LAYER:`` count, net filament, time by the same motion model.

    Understands G0/G1 (X Y Z E F), G90/G91, M82/M83, G92; acceleration and
    filament density come from ``settings`` (defaults when None).
    """
    settings = settings or SliceSettings()
    accel = settings.acceleration
    pos = [0.0, 0.0, 0.0]
    feed = settings.travel_speed
    rel_xyz = False
    rel_e = False
    e_abs = 0.0
    filament = 0.0
    time_s = 0.0
    layers = 0
    run: list[tuple[float, float]] = []
    run_speed = 0.0
    run_kind = ""

    def flush() -> float:
        nonlocal run
        t = run_time(np.array(run), run_speed, accel) if len(run) > 1 else 0.0
        run = []
        return t

    for raw in lines:
        if raw.startswith(";LAYER:"):
            layers += 1
            continue
        code, _, _ = raw.partition(";")
        words = code.split()
        if not words:
            continue
        cmd = words[0].upper()
        if cmd in ("G0", "G1"):
            vals = {w[0].upper(): float(w[1:]) for w in words[1:] if len(w) > 1}
            if "F" in vals:
                feed = vals["F"] / 60.0
            new = list(pos)
            for i, ax in enumerate("XYZ"):
                if ax in vals:
                    new[i] = pos[i] + vals[ax] if rel_xyz else vals[ax]
            de = 0.0
            if "E" in vals:
                de = vals["E"] if rel_e else vals["E"] - e_abs
                e_abs = e_abs + de
                filament += de
            moved_xy = new[0] != pos[0] or new[1] != pos[1]
            if moved_xy and new[2] == pos[2]:
                if run and (cmd != run_kind or "F" in vals or feed != run_speed):
                    time_s += flush()
                if not run:
                    run = [(pos[0], pos[1])]
                    run_kind = cmd
                    run_speed = feed
                run.append((new[0], new[1]))
            else:
                time_s += flush()
                dist = math.dist(pos, new)
                if dist > 0:
                    time_s += float(
                        segment_times(np.array([dist]), feed, np.zeros(1), np.zeros(1), accel)[0]
                    )
                elif de:
                    time_s += abs(de) / feed
            pos = new
        else:
            time_s += flush()
            if cmd == "G90":
                rel_xyz = False
            elif cmd == "G91":
                rel_xyz = True
            elif cmd == "M82":
                rel_e = False
            elif cmd == "M83":
                rel_e = True
            elif cmd == "G92":
                for w in words[1:]:
                    ax = w[0].upper()
                    if ax == "E":
                        e_abs = float(w[1:])
                    elif ax in "XYZ":
                        pos["XYZ".index(ax)] = float(w[1:])
    time_s += flush()
    return GcodeSummary(layers, filament, filament_grams(filament, settings), time_s)
