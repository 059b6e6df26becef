"""The line budget: a layer's paths as few moves as the tolerance allows, and the wire allows.

Every path is cut into pieces at its ends and at the ends of the arcs fitted
to it (:mod:`slicer.paths.arcs`, when arcs are on); the pieces that are not arcs are
simplified (Douglas-Peucker, shapely, one vectorised call) within
``resolution`` (sparse infill and support within ``infill.resolution``: where
they run does not show, and curved fields would spend most lines there). Arcs
of outer walls are fitted within :data:`OUTER_ARC` of the tolerance: an arc
strays from the level set along its whole length, where simplified lines keep
their vertices on it, and the surface is what shows. Then,
when the link's baud rate is known (``gcode.baud``), each run of
``gcode.planner_blocks`` consecutive moves that would take less time to print
than the wire needs to carry its lines marks its pieces, and those pieces alone
are simplified again within ``gcode.coarse_resolution``. Pieces keep their
ends, so paths start and end where they did.

The wire's test is a buffer's: the planner holds ``gcode.planner_blocks``
moves, so a run of short moves starves it only once the run has printed that
many lines' wire time faster than the wire carried them; then every move of
the run is marked. Outer walls are never coarsened (they are the part's
surface): the other pieces of a marked run carry the saving.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from slicer.geometry.geom import lengths, sorted_unique
from slicer.paths.arcs import Arcs, arcs_wanted, fit_arcs
from slicer.settings import SliceSettings

# bytes a move line takes on the wire with its line number and checksum (about 30
# characters of G1 X Y E and 10 of framing), and the share of the wire a host keeps busy
LINE_BYTES = 40.0
WIRE_SHARE = 0.8
# share of the tolerance arcs of outer walls may use: an arc strays from the level set
# along its whole length, where simplified lines keep their vertices on it (at 0.65 the
# arcs through the corners of a 64-gon of 12 mm radius, 0.014 mm off its sides, still fit)
OUTER_ARC = 0.65
# and at most this share of the area over the boundary length of the island an outer wall
# bounds: an arc's mean distance from the polyline it replaces, over the island's boundary,
# is the share of its area that changes, so a thin island keeps its arcs tighter (see
# budget_moves)
OUTER_FLATNESS = 0.004
# share of the tolerance the lines of outer walls at least OUTER_LOOP mm long may use.
# Simplified lines keep their vertices on the level set and cut inside its curves: on
# a torus of 128 facets a turn every other vertex went (0.017 mm off a 19 mm circle),
# and its walls lay inside PrusaSlicer's (IoU 0.964 against CuraEngine's 0.966; 0.966
# at 0.6). A short loop (a pin, a small hole) keeps the whole tolerance: its bead
# rounds it more than that, and tighter lines there took the pins' walls away from
# PrusaSlicer's (0.981 to 0.967). As before, the wire's budget never coarsens them.
OUTER_LINES = 0.6
OUTER_LOOP = 10.0


@dataclass(frozen=True)
class Moves:
    """A layer's emitted geometry: ``pts`` (m, 2) mm, path ``i`` being
    ``pts[starts[i]:ends[i]]``; the move into point ``j`` is an arc where ``arc[j]``,
    around ``centre[j]`` (m, 2) mm, counter-clockwise where ``ccw[j]``, ``length[j]`` mm
    long (for lines: the chord)."""

    pts: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    arc: np.ndarray
    centre: np.ndarray
    ccw: np.ndarray
    length: np.ndarray


def line_rate(settings: SliceSettings) -> float:
    """Move lines a second the link carries (0.0 when its baud rate is unknown)."""
    return WIRE_SHARE * settings.gcode_baud / 10.0 / LINE_BYTES


def budget_moves(
    pts: np.ndarray, starts: np.ndarray, ends: np.ndarray, speeds: np.ndarray,
    settings: SliceSettings, loose: np.ndarray | None = None,
    exact: np.ndarray | None = None, scale: np.ndarray | None = None,
) -> Moves:
    """The moves of the packed paths ``pts[starts[i]:ends[i]]`` ((m, 2) mm), printed at
    ``speeds[i]`` mm/s, within the settings' tolerances (see the module docstring).

    Paths where ``loose`` ((n,) bool: sparse infill, support) get the larger of
    ``resolution`` and ``infill.resolution``; the others ``resolution``. Paths where
    ``exact`` ((n,) bool: outer walls) keep their lines within :data:`OUTER_LINES` of
    it when :data:`OUTER_LOOP` mm long or more (within it when shorter), also when the
    wire is short; their arcs are fitted within :data:`OUTER_ARC` of it and within
    :data:`OUTER_FLATNESS` times ``scale`` ((n,) mm: the area over the boundary length of
    the island each path bounds; absent: no such bound).
    """
    path_tol = np.full(len(starts), settings.resolution)
    if loose is not None:
        path_tol[loose] = max(settings.resolution, settings.infill_resolution)
    arcs = None
    if arcs_wanted(settings) and (path_tol > 0).any():
        arc_tol = path_tol
        if exact is not None:
            outer = OUTER_ARC * path_tol
            if scale is not None:
                outer = np.minimum(outer, OUTER_FLATNESS * scale)
            arc_tol = np.where(exact, outer, path_tol)
        arcs = fit_arcs(pts, starts, ends, arc_tol)
    pa, pb, arc_of = _pieces(pts, starts, ends, arcs)
    piece_path = np.searchsorted(starts, pa, "right") - 1
    line_tol = path_tol
    if exact is not None:
        fine = exact & (_path_lengths(pts, starts, ends) >= OUTER_LOOP)
        line_tol = np.where(fine, OUTER_LINES * path_tol, path_tol)
    tol = line_tol[piece_path]  # each piece's
    keep = _simplified(pts, pa, pb, arc_of, tol)
    rate = line_rate(settings)
    coarse = np.maximum(settings.gcode_coarse_resolution, tol)
    if exact is not None:
        coarse = np.where(exact[piece_path], tol, coarse)
    if rate > 0 and (coarse > tol).any():
        hot = _starving(pts, keep, starts, speeds, rate, settings.gcode_planner_blocks)
        piece_of = np.searchsorted(pa, np.flatnonzero(hot), "right") - 1
        redo = np.zeros(len(pa), dtype=bool)
        redo[piece_of] = True
        redo &= (arc_of < 0) & (coarse > tol)
        if redo.any():
            tols = np.where(redo, coarse, tol)
            keep = _simplified(pts, pa, pb, arc_of, tols)
    return _moves(pts, keep, starts, ends, pa, arc_of, arcs)


def _path_lengths(pts: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Length of each packed path ``pts[starts[i]:ends[i]]``, (n,) mm."""
    step = np.zeros(len(pts) + 1)
    if len(pts) > 1:
        step[2:] = lengths(np.diff(pts, axis=0))
    run = np.cumsum(step)  # run[k]: the steps into points 0 .. k - 1
    out: np.ndarray = run[ends] - run[starts + 1]
    return out


def _pieces(
    pts: np.ndarray, starts: np.ndarray, ends: np.ndarray, arcs: Arcs | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pieces ``[pa[k], pb[k]]`` (point indices, inclusive) of every path, cut at path
    ends and arc ends; ``arc_of[k]`` the arc a piece is (-1: a line piece)."""
    cuts = [starts, ends - 1]
    if arcs is not None and len(arcs):
        cuts += [arcs.first, arcs.last]
    brk = sorted_unique(np.concatenate(cuts))
    path = np.searchsorted(starts, brk, "right") - 1
    same = path[1:] == path[:-1]
    pa, pb = brk[:-1][same], brk[1:][same]
    arc_of = np.full(len(pa), -1, dtype=np.int64)
    if arcs is not None and len(arcs):
        k = np.clip(np.searchsorted(arcs.first, pa), 0, len(arcs) - 1)
        hit = (arcs.first[k] == pa) & (arcs.last[k] == pb)
        arc_of[hit] = k[hit]
    return pa, pb, arc_of


def _simplified(
    pts: np.ndarray, pa: np.ndarray, pb: np.ndarray, arc_of: np.ndarray, tols: np.ndarray
) -> np.ndarray:
    """Which points are kept: (m,) bool. Line pieces are simplified within ``tols[k]`` mm;
    arc pieces keep their ends only; points outside every piece (single-point paths) stay."""
    keep = np.ones(len(pts), dtype=bool)
    n = pb - pa + 1
    inner = np.repeat(pa, n) + (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n))
    keep[inner] = False
    keep[pa] = True
    keep[pb] = True
    lines = np.flatnonzero((arc_of < 0) & (n > 2) & (tols > 0))
    plain = np.flatnonzero((arc_of < 0) & (n > 2) & (tols <= 0))
    for k in plain.tolist():
        keep[pa[k] : pb[k] + 1] = True
    if len(lines) == 0:
        return keep
    ln = n[lines]
    owner = np.repeat(np.arange(len(lines)), ln)
    idx = np.repeat(pa[lines], ln) + (np.arange(ln.sum()) - np.repeat(np.cumsum(ln) - ln, ln))
    # the point's index rides along as a third coordinate, so kept points are found
    # exactly (simplification only drops vertices, it never moves one)
    xyz = np.column_stack([pts[idx], idx.astype(np.float64)])
    geoms = shapely.linestrings(xyz, indices=owner)
    simple = np.empty(len(geoms), dtype=object)
    for tol in sorted_unique(tols[lines]).tolist():
        sel = tols[lines] == tol
        simple[sel] = shapely.simplify(geoms[sel], tol, preserve_topology=False)
    kept = shapely.get_coordinates(simple, include_z=True)[:, 2]
    keep[kept.astype(np.int64)] = True
    return keep


def _starving(
    pts: np.ndarray, keep: np.ndarray, starts: np.ndarray, speeds: np.ndarray,
    rate: float, blocks: int,
) -> np.ndarray:
    """Points whose move lies in a run that would empty a planner of ``blocks`` moves
    fed ``rate`` lines a second: (m,) bool over ``pts``.

    With ``G[k]`` the wire time of the first ``k`` moves' lines less their print time,
    move ``j`` finds the planner empty once ``G[j + 1]`` exceeds the lowest ``G``
    before it (when the planner was last full) by ``blocks / rate``; the moves since
    that lowest point are the run.
    """
    hot = np.zeros(len(pts), dtype=bool)
    idx = np.flatnonzero(keep)
    path = np.searchsorted(starts, idx, "right") - 1
    move = np.ones(len(idx), dtype=bool)
    move[np.searchsorted(idx, starts)] = False  # a path's first point ends no move
    step = np.hypot(*np.diff(pts[idx], axis=0, prepend=pts[idx[:1]]).T)
    mv = np.flatnonzero(move)
    if len(mv) <= blocks:
        return hot
    dur = step[mv] / speeds[path[mv]]
    lag = np.concatenate(([0.0], np.arange(1, len(mv) + 1) / rate - np.cumsum(dur)))
    low = np.minimum.accumulate(lag)
    since = np.maximum.accumulate(np.where(lag == low, np.arange(len(lag)), 0))
    starved = np.flatnonzero(lag[1:] - low[:-1] > blocks / rate)
    if len(starved) == 0:
        return hot
    # every move from the run's start (the lowest point before it) to the starved one
    mark = np.zeros(len(mv) + 1, dtype=np.int64)
    np.add.at(mark, since[starved], 1)
    np.add.at(mark, starved + 1, -1)
    inside = np.cumsum(mark)[:-1] > 0
    hot[idx[mv[inside]]] = True
    return hot


def _moves(
    pts: np.ndarray, keep: np.ndarray, starts: np.ndarray, ends: np.ndarray,
    pa: np.ndarray, arc_of: np.ndarray, arcs: Arcs | None,
) -> Moves:
    """The kept points as :class:`Moves`, with the arc data of each arc's end point."""
    idx = np.flatnonzero(keep)
    out = pts[idx]
    new_starts = np.searchsorted(idx, starts)
    new_ends = np.searchsorted(idx, ends)
    seg = np.diff(out, axis=0, prepend=out[:1])
    length = np.hypot(seg[:, 0], seg[:, 1])
    arc = np.zeros(len(idx), dtype=bool)
    centre = np.zeros((len(idx), 2))
    ccw = np.zeros(len(idx), dtype=bool)
    is_arc = arc_of >= 0
    if arcs is not None and is_arc.any():
        k = arc_of[is_arc]
        at = np.searchsorted(idx, arcs.last[k])
        arc[at] = True
        centre[at] = arcs.centre[k]
        ccw[at] = arcs.ccw[k]
        length[at] = arcs.length[k]
    return Moves(out, new_starts, new_ends, arc, centre, ccw, length)
