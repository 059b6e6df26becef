"""Arc fitting: stretches of a polyline replaced by circular arcs (G2/G3) within a tolerance.

Vectorised bisection over every path of a layer at once: a stretch is tried
as the circle through its first, middle and last points; it is kept when every
vertex and every segment midpoint lies within the tolerance of that circle and
the points turn one way by less than a full turn, otherwise it is cut at its
middle point and both halves are tried again, until they are too short to be
worth an arc. The work per round is a handful of numpy passes over the points,
and there are about log2(points per path) rounds. The result depends on the
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
# fraction of the tolerance the fit may use (the rest absorbs rounding to 0.001 mm)
_SHARE = 0.9


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
    within ``tol`` of every vertex it replaces and of every segment's midpoint
    (where a chord is farthest from the arc through its ends).
    """
    per_path = np.broadcast_to(np.asarray(tol, dtype=np.float64), starts.shape)
    tol_pt = np.zeros(len(pts))  # each point's path's share of its tolerance
    tol_pt[_points_of(starts, ends)] = np.repeat(per_path * _SHARE, ends - starts)
    long = (ends - starts - 1) >= MIN_SEGMENTS
    a = starts[long].astype(np.int64)
    b = (ends[long] - 1).astype(np.int64)
    kept: list[tuple[np.ndarray, ...]] = []
    while len(a):
        ok, centre, ccw, sweep, radius = _try(pts, a, b, tol_pt)
        kept.append((a[ok], b[ok], centre[ok], ccw[ok], sweep[ok], radius[ok]))
        a, b = a[~ok], b[~ok]
        m = (a + b) // 2
        halves = (m - a) >= MIN_SEGMENTS, (b - m) >= MIN_SEGMENTS
        a = np.concatenate([a[halves[0]], m[halves[1]]])
        b = np.concatenate([m[halves[0]], b[halves[1]]])
    if not kept:
        empty = np.zeros(0, dtype=np.int64)
        return Arcs(empty, empty, np.zeros((0, 2)), np.zeros(0, bool), np.zeros(0), np.zeros(0))
    cols = [np.concatenate(c) for c in zip(*kept, strict=True)]
    order = np.argsort(cols[0], kind="stable")
    return _merged(pts, [c[order] for c in cols], tol_pt)


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
    dev = np.abs(np.hypot(rel[:, 0], rel[:, 1]) - radius[owner])
    # segments: between consecutive points of the same stretch
    seg = np.ones(len(idx), dtype=bool)
    seg[np.cumsum(n) - 1] = False
    s0 = np.flatnonzero(seg)
    mid = 0.5 * (pts[idx[s0]] + pts[idx[s0] + 1]) - centre[owner[s0]]
    mid_dev = np.abs(np.hypot(mid[:, 0], mid[:, 1]) - radius[owner[s0]])
    u, v = rel[s0], rel[s0 + 1]
    step = np.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], np.einsum("ij,ij->i", u, v))
    step = np.where(ccw[owner[s0]], step, -step)  # positive when turning the arc's way
    # points and segments are grouped by stretch, each stretch has both: reduce per group
    at_pt = np.cumsum(n) - n
    at_seg = at_pt - np.arange(len(a))
    worst = np.maximum(np.maximum.reduceat(dev, at_pt), np.maximum.reduceat(mid_dev, at_seg))
    backwards = np.logical_or.reduceat((step <= 0.0) | (step >= np.pi / 2), at_seg)
    sweep = np.add.reduceat(step, at_seg)
    # a stretch that a straight line already follows within the tolerance stays a line
    chord = r - p
    chord_len = np.maximum(np.hypot(chord[:, 0], chord[:, 1]), 1e-12)
    to_pt = pts[idx] - p[owner]
    off = np.abs(chord[owner, 0] * to_pt[:, 1] - chord[owner, 1] * to_pt[:, 0]) / chord_len[owner]
    straight_worst = np.maximum.reduceat(off, at_pt)
    ok &= (worst <= tol) & ~backwards & (sweep < 2.0 * np.pi - 1e-3) & (straight_worst > tol)
    return ok, centre, ccw, sweep, radius
