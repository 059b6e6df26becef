"""G-code reading for the benchmarks: moves as arrays, layers, filament and outer-wall regions."""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

# feature-type comments that mark the outermost wall, per slicer
OUTER_WALL_TYPES = frozenset({"WALL-OUTER", "External perimeter"})
# types that may continue an outer-wall loop but never make one alone (PrusaSlicer marks the
# overhanging stretches of any perimeter, outer or inner, as "Overhang perimeter")
OUTER_WALL_CONTINUATIONS = frozenset({"Overhang perimeter"})

Z_KEY_SCALE = 100.0  # layers are matched by Z rounded to 0.01 mm
_MIN_XY_MOVE = 1e-6  # mm: shorter moves count as extruding in place (priming)
# mm²: a layer whose outer-wall loops enclose less than one square of a 0.4 mm line prints a
# dot, not an outline (PrusaSlicer lays 0.07 mm triangles where a mesh ends in a point);
# IoU means nothing at that size, so such a layer counts as having no outer wall
MIN_WALL_AREA = 0.4 * 0.4
# a move in XY that feeds filament (relative E > 0), optionally numbered with a checksum
_EXTRUDING_LINE = re.compile(r"^(?:N\d+\s+)?G[0-3]\s(?=[^;*]*[XY]-?\.?\d)[^;*]*\bE(\d*\.?\d+)")
# arcs are read as chords of at most this angle (radians) and length (mm)
ARC_STEP_RAD = np.pi / 90
ARC_STEP_MM = 0.25


@dataclass(frozen=True)
class Moves:
    """Every G0/G1/G2/G3 move of a file, in order (arcs as short chords).

    Arrays have shape (n,), dtype float64 unless stated, lengths in mm:
    ``x0, y0`` the start of each move, ``x, y, z`` its end, ``de`` the filament
    fed during it (negative for retraction), ``type_id`` (int32) the index in
    ``types`` of the last ``;TYPE:`` comment before it (-1 before the first).
    An arc (G2/G3 with I and J) is read as chords of at most 2 degrees and
    0.25 mm sharing its E by length; ``first`` (bool) is False for every
    chord of an arc but its first, so ``first.sum()`` counts G-code moves.
    """

    x0: np.ndarray
    y0: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    de: np.ndarray
    type_id: np.ndarray
    types: tuple[str, ...]
    first: np.ndarray | None = None

    @property
    def xy_length(self) -> np.ndarray:
        """Length of each move in XY, mm, shape (n,)."""
        return np.hypot(self.x - self.x0, self.y - self.y0)

    @property
    def extruding(self) -> np.ndarray:
        """Mask (n,) of moves that lay material: they move in XY and feed filament."""
        return (self.de > 0) & (self.xy_length > _MIN_XY_MOVE)

    def type_mask(self, names: Iterable[str]) -> np.ndarray:
        """Mask (n,) of moves whose feature type is one of ``names``."""
        wanted = [i for i, t in enumerate(self.types) if t in set(names)]
        return np.isin(self.type_id, np.asarray(wanted, dtype=np.int32))


@dataclass(frozen=True)
class GcodeStats:
    """What the benchmark compares between slicers for one G-code file."""

    layers: int  # distinct Z levels (0.01 mm) at which material is laid
    filament_mm: float  # filament fed by extruding moves, mm
    moves: int  # G0/G1/G2/G3 moves (an arc counts once)


def is_extruding_line(line: str) -> bool:
    """True for one G0/G1 line that moves in X or Y and feeds filament (relative E > 0)."""
    match = _EXTRUDING_LINE.match(line.strip())
    return bool(match) and float(match.group(1)) > 0


class _State:
    """Machine state while reading: position, modes, current feature type."""

    def __init__(self) -> None:
        self.pos = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        self.xyz_relative = False
        self.e_relative = False
        self.type_id = -1


def _words(code: str) -> dict[str, float]:
    """Letter -> value of the words of one command (``G1 X1 Y2`` -> X, Y); bad words skipped."""
    out: dict[str, float] = {}
    for word in code.split()[1:]:
        try:
            out[word[0].upper()] = float(word[1:])
        except (ValueError, IndexError):
            continue
    return out


def _command_part(raw: str) -> str:
    """The command of a line without comment, line number and checksum (``""`` if none)."""
    code = raw.split(";", 1)[0].strip()
    if "*" in code:
        code = code.split("*", 1)[0].strip()
    if code[:1] in ("N", "n"):
        code = code.split(None, 1)[1] if " " in code else ""
    return code


def parse_moves(lines: Iterable[str]) -> Moves:
    """Read G-code lines into :class:`Moves`.

    Understands G0-G3 (arcs as their chord), G90/G91, M82/M83, G92 and G28, and
    ``;TYPE:NAME`` comments. Line numbers (``N12``) and checksums (``*34``) are ignored,
    so a printer's executed-line log reads the same as the file.
    """
    st = _State()
    types: dict[str, int] = {}
    rows: list[tuple[float, ...]] = []
    for raw in lines:
        stripped = raw.strip()
        if stripped.startswith(";TYPE:"):
            name = stripped[6:].strip()
            st.type_id = types.setdefault(name, len(types))
            continue
        code = _command_part(stripped)
        if not code:
            continue
        cmd = code.split(None, 1)[0].upper()
        if cmd in ("G0", "G1", "G2", "G3", "G00", "G01", "G02", "G03"):
            words = _words(code)
            if words.keys() & {"X", "Y", "Z", "E"}:  # feed-rate-only lines are no moves
                if cmd in ("G2", "G3", "G02", "G03") and words.keys() & {"I", "J"}:
                    rows += _arc(st, words, clockwise=cmd in ("G2", "G02"))
                else:
                    rows.append(_move(st, words))
        elif cmd == "G92":
            words = _words(code)
            for axis in ("X", "Y", "Z", "E"):
                if axis in words:
                    st.pos[axis] = words[axis]
            if not words:
                st.pos.update(X=0.0, Y=0.0, Z=0.0, E=0.0)
        elif cmd == "M82":
            st.e_relative = False
        elif cmd == "M83":
            st.e_relative = True
        elif cmd == "G90":
            st.xyz_relative = st.e_relative = False
        elif cmd == "G91":
            st.xyz_relative = st.e_relative = True
        elif cmd == "G28":
            named = [a for a in ("X", "Y", "Z") if a in code.upper()[3:]]
            for axis in named or ("X", "Y", "Z"):
                st.pos[axis] = 0.0
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, 8)
    return Moves(
        x0=arr[:, 0], y0=arr[:, 1], x=arr[:, 2], y=arr[:, 3], z=arr[:, 4], de=arr[:, 5],
        type_id=arr[:, 6].astype(np.int32),
        types=tuple(sorted(types, key=types.__getitem__)),
        first=arr[:, 7] > 0,
    )


def _move(st: _State, words: dict[str, float]) -> tuple[float, ...]:
    """Apply one move to the state; return (x0, y0, x, y, z, de, type_id, 1)."""
    x0, y0 = st.pos["X"], st.pos["Y"]
    for axis in ("X", "Y", "Z"):
        if axis in words:
            st.pos[axis] = st.pos[axis] + words[axis] if st.xyz_relative else words[axis]
    de = 0.0
    if "E" in words:
        if st.e_relative:
            de = words["E"]
            st.pos["E"] += de
        else:
            de = words["E"] - st.pos["E"]
            st.pos["E"] = words["E"]
    return (x0, y0, st.pos["X"], st.pos["Y"], st.pos["Z"], de, st.type_id, 1.0)


def _arc(st: _State, words: dict[str, float], clockwise: bool) -> list[tuple[float, ...]]:
    """Apply one G2/G3 (I, J from the start to the centre) to the state; its chords as rows
    of :func:`_move` (an end equal to the start is a full circle)."""
    x0, y0, z0 = st.pos["X"], st.pos["Y"], st.pos["Z"]
    cx, cy = x0 + words.get("I", 0.0), y0 + words.get("J", 0.0)
    whole = _move(st, {k: v for k, v in words.items() if k in "XYZE"})
    x1, y1, z1, de = whole[2], whole[3], whole[4], whole[5]
    r = float(np.hypot(x0 - cx, y0 - cy))
    a0 = float(np.arctan2(y0 - cy, x0 - cx))
    turn = (float(np.arctan2(y1 - cy, x1 - cx)) - a0) % (2 * np.pi)
    sweep = -((2 * np.pi - turn) % (2 * np.pi)) if clockwise else turn
    if abs(sweep) < 1e-12:
        sweep = -2 * np.pi if clockwise else 2 * np.pi
    n = max(1, int(np.ceil(max(abs(sweep) / ARC_STEP_RAD, abs(sweep) * r / ARC_STEP_MM))))
    t = np.arange(1, n + 1) / n
    xs, ys = cx + r * np.cos(a0 + sweep * t), cy + r * np.sin(a0 + sweep * t)
    xs[-1], ys[-1] = x1, y1
    px = np.concatenate(([x0], xs))
    py = np.concatenate(([y0], ys))
    zs = z0 + (z1 - z0) * t
    return [(px[k], py[k], px[k + 1], py[k + 1], zs[k], de / n, whole[6], float(k == 0))
            for k in range(n)]


def read_moves(path: str | Path) -> Moves:
    """Parse a G-code file into :class:`Moves`."""
    with open(path, encoding="utf-8", errors="replace") as handle:
        return parse_moves(handle)


def stats(moves: Moves) -> GcodeStats:
    """Layer count, filament length and move count of parsed G-code."""
    ext = moves.extruding
    keys = np.unique(np.round(moves.z[ext] * Z_KEY_SCALE).astype(np.int64))
    return GcodeStats(
        layers=int(keys.size),
        filament_mm=float(moves.de[ext].sum()),
        moves=int(moves.de.size if moves.first is None else moves.first.sum()),
    )


def outer_wall_regions(
    moves: Moves,
    names: Iterable[str] = OUTER_WALL_TYPES,
    continuations: Iterable[str] = OUTER_WALL_CONTINUATIONS,
    close_tol: float = 1.0,
    min_area: float = MIN_WALL_AREA,
) -> dict[int, shapely.Geometry]:
    """Per layer, the region enclosed by the outer-wall loops, even-odd (holes stay holes).

    A loop is a run of consecutive extruding moves of an outer-wall type (``names``),
    possibly continued by ``continuations`` types; runs whose ends lie farther apart than
    ``close_tol`` mm (open walls) are left out, the others are closed. Loops made of
    continuation moves alone count only as the outermost loop of an island apart from the
    other walls (PrusaSlicer marks every wall of an island printed over air as overhang).
    Layers whose region is smaller than ``min_area`` mm² are left out. Keys are Z in
    units of 0.01 mm (``round(z * 100)``).
    """
    names, continuations = frozenset(names), frozenset(continuations)
    primary = moves.extruding & moves.type_mask(names)
    outer = moves.extruding & moves.type_mask(names | continuations)
    if not outer.any():
        return {}
    prev = np.concatenate(([False], outer[:-1]))
    starts = outer & ~prev
    chain = np.cumsum(starts)  # chain id (1-based) of every outer move
    n_chains = int(chain[-1])
    # a run of moves i..j has the vertices: start of move i, then the ends of i..j
    first_idx = np.flatnonzero(starts)
    vx = np.concatenate((moves.x0[first_idx], moves.x[outer]))
    vy = np.concatenate((moves.y0[first_idx], moves.y[outer]))
    vid = np.concatenate((chain[first_idx], chain[outer])) - 1
    order = np.concatenate((first_idx - 0.5, np.flatnonzero(outer).astype(np.float64)))
    sort = np.argsort(order, kind="stable")
    vx, vy, vid = vx[sort], vy[sort], vid[sort]
    counts = np.bincount(vid, minlength=n_chains)
    last_v = np.cumsum(counts) - 1
    first_v = last_v - counts + 1
    gap = np.hypot(vx[last_v] - vx[first_v], vy[last_v] - vy[first_v])
    has_primary = np.bincount(chain[primary] - 1, minlength=n_chains) > 0
    keep_chain = (counts >= 4) & (gap <= close_tol)
    if not keep_chain.any():
        return {}
    keep_v = keep_chain[vid]
    new_id = np.cumsum(keep_chain) - 1  # consecutive ids for the kept chains
    coords = np.column_stack((vx[keep_v], vy[keep_v]))
    rings = shapely.linearrings(coords, indices=new_id[vid[keep_v]])
    polys = shapely.make_valid(shapely.polygons(rings), method="structure",
                               keep_collapsed=False)
    keys = np.round(moves.z[first_idx][keep_chain] * Z_KEY_SCALE).astype(np.int64)
    is_primary = has_primary[keep_chain]
    regions: dict[int, shapely.Geometry] = {}
    for key in np.unique(keys):
        on_layer = keys == key
        region = _even_odd(polys[on_layer & is_primary])
        islands = _outermost(polys[on_layer & ~is_primary], outside=region)
        if islands.size:
            region = shapely.union(region, _even_odd(islands))
        if not region.is_empty and region.area >= min_area:
            regions[int(key)] = region
    return regions


def _even_odd(polys: np.ndarray) -> shapely.Geometry:
    """The even-odd combination of polygons (a ring inside another makes a hole)."""
    region = shapely.Polygon()
    for poly in polys:
        region = shapely.symmetric_difference(region, poly)
    return region


def _outermost(polys: np.ndarray, outside: shapely.Geometry) -> np.ndarray:
    """Loops that lie outside ``outside`` and inside no other loop of ``polys``.

    These are the outer walls of islands a slicer marked as overhang from end to end
    (no other wall of that island is outer); loops inside another are inner perimeters.
    """
    if polys.size == 0:
        return polys
    free = polys[~shapely.intersects(polys, outside)] if not outside.is_empty else polys
    keep = [
        i for i, poly in enumerate(free)
        if not any(j != i and shapely.contains(other, poly) for j, other in enumerate(free))
    ]
    return free[keep]


def outer_wall_centre(moves: Moves, names: Iterable[str] = OUTER_WALL_TYPES) -> np.ndarray:
    """Centre (2,) of the XY bounding box of every outer-wall extrusion, mm."""
    outer = moves.extruding & moves.type_mask(names)
    if not outer.any():
        return np.zeros(2)
    xs = np.concatenate((moves.x0[outer], moves.x[outer]))
    ys = np.concatenate((moves.y0[outer], moves.y[outer]))
    return np.array([(xs.min() + xs.max()) / 2.0, (ys.min() + ys.max()) / 2.0])


def translate_regions(
    regions: dict[int, shapely.Geometry], offset: np.ndarray
) -> dict[int, shapely.Geometry]:
    """The same regions moved by ``offset`` (2,) mm."""
    keys = list(regions)
    geoms = np.array([regions[k] for k in keys], dtype=object)
    moved = shapely.transform(geoms, lambda c: c + np.asarray(offset, dtype=np.float64))
    return dict(zip(keys, moved, strict=True))


def layer_iou(
    a: dict[int, shapely.Geometry], b: dict[int, shapely.Geometry]
) -> dict[int, float]:
    """IoU area(a & b) / area(a | b) per layer key present in either (0 where one is empty)."""
    keys = sorted(set(a) | set(b))
    empty = shapely.Polygon()
    ga = np.array([a.get(k, empty) for k in keys], dtype=object)
    gb = np.array([b.get(k, empty) for k in keys], dtype=object)
    inter = shapely.area(shapely.intersection(ga, gb))
    union = shapely.area(shapely.union(ga, gb))
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return dict(zip(keys, iou.tolist(), strict=True))


@dataclass(frozen=True)
class WallAgreement:
    """Outer-wall agreement between two G-code files."""

    mean_iou: float  # mean over the layers where either has an outer wall
    mean_iou_common: float  # mean over the layers where both have one
    layers_a: int
    layers_b: int
    offset: tuple[float, float]  # mm added to a to align it with b
    per_layer: tuple[tuple[float, float], ...] = ()  # (z in mm, IoU) for every layer

    def worst(self, count: int = 5) -> list[tuple[float, float]]:
        """The ``count`` layers of lowest IoU, as (z in mm, IoU)."""
        return sorted(self.per_layer, key=lambda zi: zi[1])[:count]


def wall_agreement(a: Moves, b: Moves, align: bool = True) -> WallAgreement:
    """Per-layer outer-wall IoU of ``a`` against ``b``; ``align`` moves a's centre onto b's."""
    ra, rb = outer_wall_regions(a), outer_wall_regions(b)
    offset = outer_wall_centre(b) - outer_wall_centre(a) if align else np.zeros(2)
    if align and ra:
        ra = translate_regions(ra, offset)
    ious = layer_iou(ra, rb)
    common = [ious[k] for k in ious if k in ra and k in rb]
    values = list(ious.values())
    return WallAgreement(
        mean_iou=float(np.mean(values)) if values else 0.0,
        mean_iou_common=float(np.mean(common)) if common else 0.0,
        layers_a=len(ra),
        layers_b=len(rb),
        offset=(float(offset[0]), float(offset[1])),
        per_layer=tuple((k / Z_KEY_SCALE, v) for k, v in ious.items()),
    )
