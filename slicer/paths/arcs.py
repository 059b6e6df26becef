"""Arc fitting: stretches of a polyline replaced by circular arcs (G2/G3) within a tolerance.

Greedy, longest piece first, vectorised over every path of a layer at once:
from a cursor the farthest point an arc reaches (its circle through the
stretch's first, middle and last points passing within the tolerance of every
point of every segment, turning one way by less than a full turn) is
found by galloping then bisection, and so is the farthest point a straight
line reaches from there; the longer piece wins and the cursor moves to its
end. Paths are walked in chunks of :data:`CHUNK` segments, every chunk at
once, so the number of rounds does not grow with a path's length; arcs that
meet at a chunk's edge are joined afterwards when their union still fits.
Cursors skip the points where no arc of :data:`MIN_SEGMENTS` segments starts
(straight and polygonal stretches, left to the line simplification), so
rounds are spent where arcs are. A sine-like infill curve takes about a third
fewer moves than with bisection at fixed midpoints. The result depends on the
points alone: the same path gives the same arcs in any layer, in any run.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slicer.settings import SliceSettings

# an arc replaces at least this many segments (fewer are cheaper as lines)
MIN_SEGMENTS = 4
# radii outside this range are left to lines, mm
MIN_RADIUS = 0.5
MAX_RADIUS = 1000.0
# the fit keeps this much of the tolerance (at most a tenth of it) for the rounding of
# X, Y, I and J to 0.001 mm, mm
_ROUNDING = 0.002
# segments of a path walked apart, at once (arcs across their edges are joined after), at
# a tolerance of _CHUNK_TOL mm; as many more times segments at so many times that
CHUNK = 32
_CHUNK_TOL = 0.025


@dataclass(frozen=True)
class Arcs:
    """Arcs over packed points: arc ``k`` runs from point ``first[k]`` to ``last[k]``
    (indices into the points, ``first < last``, within one path) around ``centre[k]``
    (k, 2) mm, counter-clockwise where ``ccw[k]``, sweeping ``sweep[k]`` radians (> 0)
    on a circle of ``radius[k]`` mm. Sorted by ``first``; arcs never overlap."""

    first: NDArray[np.int64]
    last: NDArray[np.int64]
    centre: NDArray[np.float64]
    ccw: NDArray[np.bool_]
    sweep: NDArray[np.float64]
    radius: NDArray[np.float64]

    @property
    def length(self) -> NDArray[np.float64]:
        """Length of each arc, (k,) mm."""
        return self.radius * self.sweep

    def __len__(self) -> int:
        return len(self.first)


def arcs_wanted(settings: SliceSettings) -> bool:
    """Whether G-code gets arcs: ``gcode.arcs = "on"`` (``auto`` is settled by the host
    before slicing, :func:`for_firmware`; unsettled it means off)."""
    return settings.gcode_arcs == "on"


def for_printer(
    settings: SliceSettings, capabilities: Iterable[str], baud: int = 0
) -> SliceSettings:
    """The settings for a connected printer: ``gcode.arcs = "auto"`` becomes ``on`` when
    its M115 reported ``Cap:ARCS:1`` (``capabilities`` holds the names reported as 1),
    else ``off``; ``gcode.baud`` left at 0 becomes the link's ``baud`` (0: unknown)."""
    changes: dict[str, object] = {}
    if settings.gcode_arcs == "auto":
        changes["gcode.arcs"] = "on" if "ARCS" in set(capabilities) else "off"
    if settings.gcode_baud == 0 and baud > 0:
        changes["gcode.baud"] = int(baud)
    return SliceSettings.from_mapping(changes, base=settings) if changes else settings


def fit_arcs(
    pts: np.ndarray, starts: np.ndarray, ends: np.ndarray, tol: float | np.ndarray
) -> Arcs:
    """Arcs within ``tol`` mm (one for all, or (n,) one per path) of the polylines
    ``pts[starts[i]:ends[i]]`` ((m, 2) mm).

    Each arc covers at least :data:`MIN_SEGMENTS` segments; its circle passes
    within ``tol`` of every point of the segments it replaces (a segment is farthest
    outside it at an end, farthest inside where it passes nearest the centre), and it reaches
    farther than a straight line from its first point would.
    """
    per_path = np.broadcast_to(np.asarray(tol, dtype=np.float64), starts.shape)
    per_path = per_path - np.minimum(_ROUNDING, 0.1 * per_path)
    tol_pt = np.zeros(len(pts))  # each point's path's tolerance, less the rounding's share
    tol_pt[_points_of(starts, ends)] = np.repeat(per_path, ends - starts)
    long = (ends - starts - 1) >= MIN_SEGMENTS
    s, e = starts[long].astype(np.int64), ends[long].astype(np.int64)
    # a chunk holds about as many pieces whatever the tolerance (pieces grow with it)
    chunk = (CHUNK * np.maximum(1.0, np.rint(per_path[long] / _CHUNK_TOL))).astype(np.int64)
    first, last = _greedy(pts, s, e, tol_pt, chunk)
    if len(first) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Arcs(empty, empty, np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0), np.zeros(0))
    order = np.argsort(first, kind="stable")
    first, last = first[order], last[order]
    _, centre, ccw, sweep, radius = _try(pts, first, last, tol_pt)
    return _merged(pts, [first, last, centre, ccw, sweep, radius], tol_pt)


def _greedy(
    pts: np.ndarray, s: NDArray[np.int64], e: NDArray[np.int64], tol_pt: np.ndarray,
    chunk: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """First and last point of the arcs the greedy walk takes on the paths ``[s[i], e[i])``
    (each of at least :data:`MIN_SEGMENTS` segments), in chunks of ``chunk[i]`` segments,
    all at once."""
    n_pts = len(pts)
    idx = _points_of(s, e)
    path_last = np.repeat(e - 1, e - s)
    room = idx + MIN_SEGMENTS <= path_last
    starts_arc = np.zeros(n_pts + 1, dtype=bool)  # an arc of MIN_SEGMENTS starts there
    if room.any():
        cand = idx[room]
        starts_arc[cand] = _try(pts, cand, cand + MIN_SEGMENTS, tol_pt)[0]
    starts_arc[n_pts] = True
    # the first point at or after each point where an arc starts (n_pts: none)
    where = np.where(starts_arc, np.arange(n_pts + 1), n_pts)
    next_start = np.minimum.accumulate(where[::-1])[::-1]
    segs = e - 1 - s
    count = (segs + chunk - 1) // chunk
    size = np.repeat(chunk, count)
    lo_pt = np.repeat(s, count) + size * (
        np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count))
    end = np.minimum(lo_pt + size, np.repeat(e - 1, count))  # each chunk's last point
    cur = next_start[lo_pt]
    arc = _Search(len(cur))
    line = _Search(len(cur))
    line_phase = np.zeros(len(cur), dtype=bool)
    live = np.flatnonzero(cur + MIN_SEGMENTS <= end)
    arc.start(live, cur[live] + MIN_SEGMENTS, end[live], 2 * MIN_SEGMENTS)
    got_first: list[NDArray[np.int64]] = []
    got_last: list[NDArray[np.int64]] = []
    while len(live):
        # arcs: the farthest point from the cursor (the first MIN_SEGMENTS are known to fit)
        rows = live[~line_phase[live] & ~arc.done[live]]
        if len(rows):
            j = arc.candidate(rows, cur[rows])
            arc.update(rows, j, _try(pts, cur[rows], j, tol_pt)[0], end[rows])
        # lines: does one reach the arc's end, and how far then
        rows = live[line_phase[live] & ~line.done[live]]
        if len(rows):
            j = line.candidate(rows, cur[rows])
            line.update(rows, j, _straight(pts, cur[rows], j, tol_pt), end[rows])
        found = live[~line_phase[live] & arc.done[live]]
        line_phase[found] = True
        # a line that falls short of the arc's end loses at once
        line.start(found, cur[found], end[found], arc.lo[found] - cur[found], strict=True)
        walked = live[line_phase[live] & line.done[live]]
        if len(walked) == 0:
            continue
        reach_arc, reach_line = arc.lo[walked], line.lo[walked]
        is_arc = reach_arc > reach_line
        got_first.append(cur[walked][is_arc])
        got_last.append(reach_arc[is_arc])
        cur[walked] = next_start[np.where(is_arc, reach_arc, reach_line)]
        line_phase[walked] = False
        again = walked[cur[walked] + MIN_SEGMENTS <= end[walked]]
        arc.start(again, cur[again] + MIN_SEGMENTS, end[again], 2 * MIN_SEGMENTS)
        live = live[cur[live] + MIN_SEGMENTS <= end[live]]
    if not got_first:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(got_first), np.concatenate(got_last)


class _Search:
    """Farthest fitting end of many stretches at once: galloping (the stretch doubles)
    until one fails or reaches its chunk's end, then bisection. ``lo`` is the farthest
    end known to fit (the start itself when none is), ``hi`` the nearest known not to."""

    def __init__(self, n: int) -> None:
        self.lo = np.zeros(n, dtype=np.int64)
        self.hi = np.zeros(n, dtype=np.int64)
        self.step = np.zeros(n, dtype=np.int64)
        self.galloping = np.zeros(n, dtype=bool)
        self.strict = np.zeros(n, dtype=bool)
        self.done = np.ones(n, dtype=bool)

    def start(
        self, rows: np.ndarray, known: np.ndarray, end: np.ndarray, step: np.ndarray | int,
        strict: bool = False,
    ) -> None:
        """Begin at ``rows`` with the end ``known`` (to fit, or the start itself) and the
        first try ``step`` segments past the start, within ``end``; ``strict``: the search
        ends when that first try fails."""
        self.lo[rows] = known
        self.hi[rows] = end + 1
        self.step[rows] = step
        self.galloping[rows] = True
        self.strict[rows] = strict
        self.done[rows] = known >= end

    def candidate(self, rows: np.ndarray, cur: np.ndarray) -> np.ndarray:
        """The end to try next for ``rows`` whose stretches start at ``cur``."""
        reach = np.minimum(cur + self.step[rows], self.hi[rows] - 1)
        out: np.ndarray = np.where(self.galloping[rows], reach,
                                   (self.lo[rows] + self.hi[rows]) // 2)
        return out

    def update(self, rows: np.ndarray, j: np.ndarray, ok: np.ndarray, end: np.ndarray) -> None:
        """Record whether the stretches of ``rows`` ending at ``j`` fit (``ok``)."""
        self.lo[rows[ok]] = j[ok]
        self.hi[rows[~ok]] = j[~ok]
        self.step[rows] *= 2
        stop = ~ok | (j >= end)
        self.galloping[rows[stop]] = False
        self.done[rows] = (~self.galloping[rows] & (self.hi[rows] - self.lo[rows] <= 1)) | (
            self.strict[rows] & ~ok)
        self.strict[rows] = False


def _points_of(starts: NDArray[np.int64], ends: NDArray[np.int64]) -> NDArray[np.int64]:
    """Indices of every point of the paths ``[starts[i], ends[i])``, in order."""
    n = ends - starts
    # numpy's stubs lose the dtype in the mixed-width arithmetic: it is int64
    index: NDArray[np.int64] = np.repeat(starts, n) + (
        np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    )
    return index


def _merged(pts: np.ndarray, cols: list[np.ndarray], tol: np.ndarray) -> Arcs:
    """Join neighbouring arcs (one ends where the next begins) while their union is still
    an arc within ``tol`` (per point, (m,) mm): pairs are tried all at once, every other
    one of a chain of joinable pairs is joined, and rounds repeat until none joins."""
    first, last, centre, ccw, sweep, radius = cols
    while len(first) > 1:
        cand = np.flatnonzero(last[:-1] == first[1:])
        if len(cand) == 0:
            break
        ok, c, w, sw, r = _try(pts, first[cand], last[cand + 1], tol)
        good = cand[ok]
        if len(good) == 0:
            break
        # a chain of joinable pairs k, k+1, k+2 ...: join the 1st, 3rd, ... of it
        run_start = np.ones(len(good), dtype=bool)
        run_start[1:] = good[1:] != good[:-1] + 1
        pos = np.arange(len(good)) - np.maximum.accumulate(np.where(run_start,
                                                                    np.arange(len(good)), 0))
        take = pos % 2 == 0
        k = good[take]
        sel = np.flatnonzero(ok)[take]
        last[k] = last[k + 1]
        centre[k], ccw[k], sweep[k], radius[k] = c[sel], w[sel], sw[sel], r[sel]
        drop = np.ones(len(first), dtype=bool)
        drop[k + 1] = False
        first, last, centre, ccw, sweep, radius = (
            a[drop] for a in (first, last, centre, ccw, sweep, radius))
    return Arcs(first, last, centre, ccw, sweep, radius)


def _try(
    pts: np.ndarray, a: np.ndarray, b: np.ndarray, tol_pt: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Which stretches ``pts[a[k]..b[k]]`` are arcs within the tolerance of their first
    point (``tol_pt`` (m,) mm); with each one's centre (k, 2), direction (ccw), sweep
    (rad) and radius."""
    tol = tol_pt[a]
    m = (a + b) // 2
    p, q, r = pts[a], pts[m], pts[b]
    # circumcentre of p, q, r
    bx, by = q[:, 0] - p[:, 0], q[:, 1] - p[:, 1]
    cx, cy = r[:, 0] - p[:, 0], r[:, 1] - p[:, 1]
    d = 2.0 * (bx * cy - by * cx)
    flat = np.abs(d) < 1e-12
    d = np.where(flat, 1.0, d)
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ux = (cy * b2 - by * c2) / d
    uy = (bx * c2 - cx * b2) / d
    centre = p + np.column_stack([ux, uy])
    radius = np.hypot(ux, uy)
    ccw = d > 0
    ok = ~flat & (radius >= MIN_RADIUS) & (radius <= MAX_RADIUS)
    # every point of every stretch: its stretch number and index
    n = b - a + 1
    owner = np.repeat(np.arange(len(a)), n)
    idx = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(a, n)
    rel = pts[idx] - centre[owner]
    # within the tolerance of the circle: (r - tol)^2 <= |rel|^2 <= (r + tol)^2
    inner = np.maximum(radius - tol, 0.0) ** 2
    outer = (radius + tol) ** 2
    dist2 = np.einsum("ij,ij->i", rel, rel)
    off = (dist2 < inner[owner]) | (dist2 > outer[owner])
    # segments: between consecutive points of the same stretch
    seg = np.ones(len(idx), dtype=bool)
    seg[np.cumsum(n) - 1] = False
    s0 = np.flatnonzero(seg)
    o0 = owner[s0]
    u, v = rel[s0], rel[s0 + 1]
    # a segment is farthest outside the circle at an end, farthest inside where it
    # passes nearest the centre
    w = v - u
    along = -np.einsum("ij,ij->i", u, w) / np.maximum(np.einsum("ij,ij->i", w, w), 1e-24)
    near = u + np.clip(along, 0.0, 1.0)[:, None] * w
    off_mid = np.einsum("ij,ij->i", near, near) < inner[o0]
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    # each step turns the arc's way by less than a quarter turn
    turn = np.where(ccw[o0], cross, -cross)
    backwards = (turn <= 0.0) | (np.einsum("ij,ij->i", u, v) <= 0.0)
    # points and segments are grouped by stretch, each stretch has both: reduce per group
    at_pt = np.cumsum(n) - n
    at_seg = at_pt - np.arange(len(a))
    bad = np.logical_or.reduceat(off, at_pt) | np.logical_or.reduceat(off_mid | backwards, at_seg)
    # the sweep, as the two halves' (each less than a full turn when every step is short)
    sweep = _turn(p - centre, q - centre, ccw) + _turn(q - centre, r - centre, ccw)
    ok &= ~bad & (sweep < 2.0 * np.pi - 1e-3)
    return ok, centre, ccw, sweep, radius


def _turn(u: np.ndarray, v: np.ndarray, ccw: np.ndarray) -> np.ndarray:
    """Angle from ``u`` to ``v`` (k, 2) turning counter-clockwise where ``ccw`` (k,), else
    clockwise: (k,) radians in [0, 2 pi)."""
    angle = np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], np.einsum("ij,ij->i", u, v))
    angle = np.where(ccw, angle, -angle)
    out: np.ndarray = np.mod(angle, 2.0 * np.pi)
    return out


def _straight(pts: np.ndarray, a: np.ndarray, b: np.ndarray, tol_pt: np.ndarray) -> np.ndarray:
    """Which stretches ``pts[a[k]..b[k]]`` a straight line from the first point to the last
    follows within the tolerance of the first point (``tol_pt`` (m,) mm): (k,) bool. Every
    point lies within it of the line and projects onto the chord (give or take it)."""
    tol = tol_pt[a]
    n = b - a + 1
    owner = np.repeat(np.arange(len(a)), n)
    idx = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + np.repeat(a, n)
    chord = pts[b] - pts[a]
    length = np.maximum(np.hypot(chord[:, 0], chord[:, 1]), 1e-12)
    rel = pts[idx] - pts[a][owner]
    off = np.abs(chord[owner, 0] * rel[:, 1] - chord[owner, 1] * rel[:, 0]) / length[owner]
    along = (chord[owner, 0] * rel[:, 0] + chord[owner, 1] * rel[:, 1]) / length[owner]
    bad = (off > tol[owner]) | (along < -tol[owner]) | (along > length[owner] + tol[owner])
    at_pt = np.cumsum(n) - n
    out: np.ndarray = ~np.logical_or.reduceat(bad, at_pt)
    return out
