"""SlicePlan: the whole-model pass once, then any layer's G-code on demand.

The whole-model pass loads, checks, repairs and places the mesh and fixes the
layer heights; the layer outlines (shapely polygons with a body number each)
are cut a block of layers at a time when first asked for. Every per-layer
product (walls, skins, infill, support, G-code) is computed from the plan and
the layer index alone, so layers can be sliced in any order, from any thread,
with identical bytes.
"""

from __future__ import annotations

import functools
import importlib
import os
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np
import shapely

from slicer.errors import ModelError
from slicer.fields.base import InfillField, LayerContext, get_field
from slicer.fields.linear import LinearField
from slicer.geometry import geom
from slicer.geometry.geom import private_copy
from slicer.input.lazycut import LazyOutlines
from slicer.input.mesh import PlacedMesh, prepare, read_stl
from slicer.output import gcode
from slicer.output.labels import nearest_body
from slicer.paths.detour import avoid_region
from slicer.paths.islands import island_domains
from slicer.paths.layer import LayerRegions, Path, fill_distance, layer_paths_many
from slicer.paths.skins import SkinCache
from slicer.settings import SettingsError, SliceSettings

if TYPE_CHECKING:
    from slicer.input.forkcut import CutAway

_EMPTY = np.empty(0, dtype=object)
_NO_BODY = np.empty(0, dtype=np.int64)
# distinct layers whose G-code is kept for the identical layers that follow
_REPEATS = 4
# layers whose toolpaths are made together (one pass over their islands' walls and
# their runs' joints)
_TOGETHER = 16


# modules that some layers load on first use (a narrow skin's lines, curved paths'
# ordering, supports): scipy.spatial alone takes 0.5 s or more to load on a small board
ON_DEMAND_MODULES = (
    "scipy.spatial", "slicer.fields.paths", "slicer.paths.order", "slicer.paths.support"
)


def load_on_demand_modules() -> None:
    """Load the modules that some layers load on first use, so that a long-running
    process (the daemon) pays for them once at start-up instead of in the first job
    whose layer needs one, while the printer waits."""
    for name in ON_DEMAND_MODULES:
        importlib.import_module(name)


def layer_tops(height: float, settings: SliceSettings) -> np.ndarray:
    """Top z of every layer (n,) float64 mm: a layer exists while its middle is inside the model."""
    first = settings.first_layer_height
    h = settings.layer_height
    if height <= first / 2.0:
        return np.array([first])
    n = 1 + max(0, int(np.ceil((height - first) / h - 0.5 - 1e-9)))
    tops = first + np.arange(n) * h
    return tops


# cut planes lie this far (mm) below the layer middle: a layer whose middle is at
# the height of a horizontal face is cut just below that face, whichever way
# float32 rounded it
PLANE_TIE = 5e-5


def cut_planes(tops: np.ndarray, settings: SliceSettings) -> np.ndarray:
    """Where each layer is cut: the middle of the layer less :data:`PLANE_TIE`, mm.

    A horizontal face at exactly a layer's middle height is a tie between the
    part below it and the part above it. STL stores float32 (a few 1e-6 mm of
    rounding at printable heights), so without a rule the tie would fall either
    way from one face to the next. Cutting ``PLANE_TIE`` (50 nm, above float32's
    rounding up to 256 mm, far below any printable detail) below the middle
    settles it: what starts at the middle height is cut in the layer above,
    what ends there in this layer, as PrusaSlicer and CuraEngine settle it.
    """
    planes = tops - settings.layer_height / 2.0
    planes[0] = settings.first_layer_height / 2.0
    return planes - PLANE_TIE


@dataclass(frozen=True)
class _Geometry:
    """What the whole-model pass produces, shared by plans with different settings.

    ``outlines`` cuts blocks of layers on first use (thread-safe); ``body_map``
    maps a mesh shell to its object number.
    """

    tops: np.ndarray
    outlines: LazyOutlines  # (n,) MultiPolygon per layer, cut on demand
    body_map: np.ndarray
    bounds: tuple[float, float, float, float]
    body_count: int
    bed: tuple[float, float, float]
    mesh_warnings: tuple[str, ...]

    def bodies(self, i: int) -> np.ndarray:
        """Object number of each polygon of layer ``i``'s outline, (p,) int64."""
        body = self.outlines.polygons(i)[1]
        return self.body_map[body] if len(body) else body


class SlicePlan:
    """A model cut into layer outlines, ready to slice any layer on demand (thread-safe)."""

    def __init__(
        self, geometry: _Geometry, settings: SliceSettings, skins: SkinCache | None = None
    ) -> None:
        self._geo = geometry
        self.settings = settings
        self._field = get_field(settings)
        self._skins = (
            skins
            if skins is not None
            else SkinCache(
                geometry.outlines,
                fill_distance(settings),
                settings.top_layers,
                settings.bottom_layers,
                inward=functools.partial(
                    island_domains, w=settings.line_width, perimeters=settings.perimeters,
                    fill_distance=fill_distance(settings), wall_order=settings.wall_order),
            )
        )
        self._support: list[shapely.Geometry] | None = None
        self._interface: list[shapely.Geometry] | None = None
        if settings.support_enabled:
            self._plan_support()
        # prismatic parts repeat layers: a layer with the same outline, skin and
        # hatch direction as one sliced lately has the same paths (see _repeat_key)
        self._repeats: OrderedDict[bytes, gcode.LayerCode] = OrderedDict()
        self._repeats_lock = threading.Lock()
        self._reuse = isinstance(self._field, LinearField) and self._support is None

    # ---- construction -------------------------------------------------
    @classmethod
    def from_file(
        cls,
        path: str | os.PathLike[str],
        settings: SliceSettings,
        bed: tuple[float, float, float] = (220.0, 220.0, 250.0),
    ) -> SlicePlan:
        """Load, validate, repair and place on the bed; fix the layer heights.

        Layer outlines are cut a block of layers at a time on first use (a
        model of several shells is cut whole here, to number its objects).
        Raises ModelError with a specific reason when the file cannot be sliced.
        """
        bed = (float(bed[0]), float(bed[1]), float(bed[2]))
        mesh = prepare(*read_stl(path), bed, in_place=True)
        geometry = _cut_model(mesh, settings, bed)
        del mesh
        return cls(geometry, settings)

    @classmethod
    def from_mesh(
        cls,
        vertices: np.ndarray,
        faces: np.ndarray,
        settings: SliceSettings,
        bed: tuple[float, float, float] = (220.0, 220.0, 250.0),
    ) -> SlicePlan:
        """As :meth:`from_file`, for vertices (v, 3) mm and faces (f, 3) already in memory."""
        bed = (float(bed[0]), float(bed[1]), float(bed[2]))
        mesh = prepare(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64),
                       bed)
        geometry = _cut_model(mesh, settings, bed)
        del mesh
        return cls(geometry, settings)

    def with_settings(self, settings: SliceSettings) -> SlicePlan:
        """The same geometry with new per-layer settings; layer heights may not change."""
        for key in ("layer_height", "first_layer_height"):
            if getattr(settings, key) != getattr(self.settings, key):
                raise SettingsError(key, "cannot change once a model is cut into layers")
        same_skins = all(
            getattr(settings, key) == getattr(self.settings, key)
            for key in ("top_layers", "bottom_layers", "line_width", "perimeters", "wall_order")
        ) and fill_distance(settings) == fill_distance(self.settings)
        return SlicePlan(self._geo, settings, self._skins if same_skins else None)

    def cut_all(self, threads: int = 1) -> None:
        """Cut every layer outline not cut yet (e.g. before forking workers that share them).

        ``threads`` > 1 cuts blocks of layers on that many threads at once.
        """
        self._geo.outlines.cut_all(threads)

    def cut_away(self, reserved_layers: int = 0) -> CutAway | None:
        """Start cutting the outlines not cut yet in a forked process while this one
        goes on (:meth:`LazyOutlines.cut_away`): only where forking is safe, as
        before forking workers that share the outlines; its ``meet()`` ends it."""
        return self._geo.outlines.cut_away(reserved_layers)

    def forget_before(self, layer: int) -> None:
        """Let go of the outlines and skins of the blocks of layers all below ``layer``
        (:meth:`LazyOutlines.forget_before`): a print that goes up layer by layer holds
        a window of them, not the whole model. A layer below, asked for again, is cut
        and solved again: the same paths, some ms later."""
        self._geo.outlines.forget_before(layer)
        self._skins.forget_before(layer)

    def held_blocks(self) -> tuple[int, int]:
        """Blocks of layer outlines and of skins held now (what :meth:`forget_before`
        bounds)."""
        return self._geo.outlines.held_blocks, self._skins.held_blocks

    def cut_estimate(self) -> float:
        """Estimated seconds to cut the outlines not cut yet on one thread
        (:meth:`LazyOutlines.cut_estimate`)."""
        return self._geo.outlines.cut_estimate()

    # ---- facts ----------------------------------------------------------
    @property
    def layer_count(self) -> int:
        """Number of layers."""
        return len(self._geo.tops)

    def layer_z(self, i: int) -> float:
        """Top of layer ``i`` (the nozzle height while printing it), mm."""
        return float(self._geo.tops[self._check(i)])

    def layer_height(self, i: int) -> float:
        """Thickness of layer ``i``, mm."""
        self._check(i)
        return self.settings.first_layer_height if i == 0 else self.settings.layer_height

    @property
    def warnings(self) -> list[str]:
        """What was repaired or worked around over the whole model, one sentence each.

        Outline repairs are known once every layer is cut: reading this cuts
        the layers not cut yet (cheap at the end of a job, which has cut them all).
        """
        self._geo.outlines.cut_all()
        return self.warnings_so_far

    @property
    def warnings_so_far(self) -> list[str]:
        """The warnings of :attr:`warnings` for the layers cut so far (cuts nothing)."""
        return _warnings(self._geo)

    @property
    def body_count(self) -> int:
        """Separate objects in the model (``excluded_bodies`` numbers them 0..n-1)."""
        return self._geo.body_count

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the placed model on the bed, mm."""
        return self._geo.bounds

    @property
    def bed(self) -> tuple[float, float, float]:
        """Build volume x, y, z, mm."""
        return self._geo.bed

    def outline(self, i: int, excluded_bodies: frozenset[int] = frozenset()) -> shapely.Geometry:
        """Layer ``i``'s solid region as a MultiPolygon, mm.

        The plan's own object, shared by every thread: use it read-only and
        never ``shapely.prepare`` it (prepare a copy instead).
        """
        i = self._check(i)
        if excluded_bodies and np.isin(self._geo.bodies(i), list(excluded_bodies)).any():
            return _multi(self._islands(i, excluded_bodies))
        return self._geo.outlines[i]

    def layer_bodies(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Layer ``i``'s outline polygons, (p,) shapely objects, and each one's body, (p,) int64."""
        i = self._check(i)
        return shapely.get_parts(self._geo.outlines[i]), self._geo.bodies(i)

    # ---- per layer ------------------------------------------------------
    @property
    def infill_field(self) -> InfillField:
        """The infill field strategy the settings select."""
        return self._field

    def layer_context(
        self, i: int, excluded_bodies: frozenset[int] = frozenset()
    ) -> LayerContext:
        """What the infill field sees of layer ``i`` (a private copy of its domain)."""
        i = self._check(i)
        return LayerContext(
            index=i,
            z=float(self._geo.tops[i]),
            domain=_private(self.outline(i, excluded_bodies)),
            bounds=self._geo.bounds,
            settings=self.settings,
        )

    def layer_toolpaths(self, i: int, excluded_bodies: frozenset[int] = frozenset()) -> list[Path]:
        """Every toolpath of layer ``i`` in print order."""
        return self._toolpaths([self._check(i)], excluded_bodies)[0]

    def _toolpaths(self, layers: Sequence[int], excluded: frozenset[int]) -> list[list[Path]]:
        """The toolpaths of ``layers`` (checked indices), made together
        (:func:`slicer.paths.layer.layer_paths_many`)."""
        inputs = []
        for i in layers:
            islands = self._islands(i, excluded)
            if self._reuse:  # the linear field and the walls never read the domain: no copy
                ctx = LayerContext(
                    index=i,
                    z=float(self._geo.tops[i]),
                    domain=self.outline(i, excluded),
                    bounds=self._geo.bounds,
                    settings=self.settings,
                )
            else:
                ctx = self.layer_context(i, excluded)
            skin = self._skins.get(i)
            if excluded and skin is not None:  # no skin over a cancelled body
                skin = geom.intersection(skin, ctx.domain)
            regions = LayerRegions(
                islands=islands,
                skin=skin,
                support=_private(self._support[i]) if self._support is not None else None,
                interface=(_private(self._interface[i]) if self._interface is not None
                           else None),
            )
            inputs.append((regions, ctx))
        support_fn = None
        if self._support is not None:
            from slicer.paths.support import support_paths

            support_fn = support_paths
        return layer_paths_many(inputs, self._field, support_fn)

    def layer_code(self, i: int, excluded_bodies: frozenset[int] = frozenset()) -> gcode.LayerCode:
        """Layer ``i``'s G-code with its filament (mm) and time (s).

        A layer identical to one of the last few sliced (same outline, skin and
        hatch direction) reuses that layer's lines with its own number and height.
        """
        return self.layer_codes(i, i + 1, excluded_bodies)[0]

    def layer_codes(
        self, lo: int, hi: int, excluded_bodies: frozenset[int] = frozenset()
    ) -> list[gcode.LayerCode]:
        """:meth:`layer_code` of layers ``lo .. hi - 1``, the same bytes as one by one:
        their toolpaths and G-code are made a few layers at a time
        (:meth:`_toolpath_chunks`, :func:`slicer.output.gcode.layer_codes`), which spends less
        per layer on small layers."""
        made: list[gcode.LayerCode | None] = []
        first_of: dict[bytes, int] = {}  # a key's first layer to be made here
        later: list[tuple[int, int]] = []  # (slot, slot of the layer it repeats)
        wanted: list[tuple[int, bytes | None, int]] = []  # (slot, key, layer) to make
        for i in (self._check(k) for k in range(self._check(lo), hi)):
            key = self._repeat_key(i, excluded_bodies)
            if key is not None:
                with self._repeats_lock:
                    seen = self._repeats.get(key)
                if seen is not None:
                    made.append(seen.moved_to(i, self.layer_z(i)))
                    continue
                if key in first_of:
                    later.append((len(made), first_of[key]))
                    made.append(None)
                    continue
                first_of[key] = len(made)
            wanted.append((len(made), key, i))
            made.append(None)
        for chunk in self._toolpath_chunks(wanted):
            paths = self._toolpaths([i for _, _, i in chunk], excluded_bodies)
            self._make_codes([(slot, key, self._layer_job(i, layer_paths, excluded_bodies))
                              for (slot, key, i), layer_paths in zip(chunk, paths, strict=True)],
                             made)
        for k, source in later:
            code = made[source]
            assert code is not None
            made[k] = code.moved_to(lo + k, self.layer_z(lo + k))
        return cast(list[gcode.LayerCode], made)

    def _toolpath_chunks(
        self, wanted: list[tuple[int, bytes | None, int]]
    ) -> list[list[tuple[int, bytes | None, int]]]:
        """``wanted`` (slot, key, layer) in runs whose toolpaths are made together: at
        most :data:`_TOGETHER` layers, and no more outline points than
        :data:`slicer.output.gcode.BATCH_POINTS` unless one layer alone has more (a layer of
        thousands of loops is made alone: the block's paths are held together)."""
        chunks: list[list[tuple[int, bytes | None, int]]] = []
        points = 0
        for item in wanted:
            size = int(shapely.get_num_coordinates(self._geo.outlines[item[2]]))
            if not chunks or len(chunks[-1]) >= _TOGETHER or (
                    points + size > gcode.BATCH_POINTS):
                chunks.append([])
                points = 0
            chunks[-1].append(item)
            points += size
        return chunks

    def _layer_job(
        self, i: int, paths: list[Path], excluded: frozenset[int]
    ) -> gcode.LayerJob:
        """What layer ``i``'s G-code is made from: its toolpaths ``paths``, outline and
        owners."""
        outline = self.outline(i, excluded)
        if self._support is not None and self._support[i] is not None:
            outline = geom.union(outline, self._support[i])
        labelled = self.settings.gcode_labels and self.body_count >= 2
        owners = self._path_bodies(i, paths, excluded) if labelled else None
        return gcode.LayerJob(i, self.layer_z(i), self.layer_height(i), paths, outline,
                              self._avoid(i, excluded), owners)

    def _make_codes(
        self, pending: list[tuple[int, bytes | None, gcode.LayerJob]],
        made: list[gcode.LayerCode | None],
    ) -> None:
        """The G-code of the ``pending`` jobs into their slots of ``made``, kept for the
        layers that repeat them."""
        codes = gcode.layer_codes([job for _, _, job in pending], self.settings)
        for (slot, key, _), code in zip(pending, codes, strict=True):
            made[slot] = code
            if key is not None:
                with self._repeats_lock:
                    self._repeats[key] = gcode.LayerCode(
                        list(code.lines), code.filament_mm, code.time_s, code.z_line,
                        code.spans,
                    )
                    while len(self._repeats) > _REPEATS:
                        self._repeats.popitem(last=False)

    def layer_gcode(self, i: int, excluded_bodies: frozenset[int] = frozenset()) -> list[str]:
        """G-code lines of layer ``i`` (starting with ``;LAYER:i``); the same bytes every time."""
        return self.layer_code(i, excluded_bodies).lines

    def entry_region(self, i: int, excluded_bodies: frozenset[int]) -> shapely.Geometry | None:
        """The region the travel into layer ``i`` keeps out of (:mod:`slicer.output.entry`): the
        ``excluded_bodies``' outlines on layer ``i`` and the layer below (where the travel
        runs), grown by :data:`slicer.paths.detour.MARGIN`; None without any."""
        i = self._check(i)
        if not excluded_bodies:
            return None
        excluded = list(excluded_bodies)
        parts = []
        for layer in range(max(0, i - 1), i + 1):
            polys = shapely.get_parts(self._geo.outlines[layer])
            if len(polys):
                parts.append(polys[np.isin(self._geo.bodies(layer), excluded)])
        return avoid_region(np.concatenate(parts)) if parts else None

    def start_gcode(self) -> list[str]:
        """Heating, homing and modes before layer 0."""
        return gcode.start_block(self.settings)

    def end_gcode(self) -> list[str]:
        """Retract, lift, heaters and motors off."""
        return gcode.end_block(self.settings, float(self._geo.tops[-1]), self._geo.bed[2])

    def resume_gcode(self, i: int) -> list[str]:
        """Preamble that restarts an interrupted print at layer ``i``."""
        i = self._check(i)
        below = float(self._geo.tops[i - 1]) if i > 0 else 0.0
        return gcode.resume_block(self.settings, i, below)

    # ---- internals ------------------------------------------------------
    def _repeat_key(self, i: int, excluded: frozenset[int]) -> bytes | None:
        """What layer ``i``'s G-code depends on besides its number and height, as bytes.

        With the linear field and no support a layer's paths follow from its
        islands, its skin and the hatch direction (the parity of ``i``) alone;
        the first layer (own speeds and height) and the layer that starts the
        fan differ in more, and get no key (None). Coordinates are compared
        exactly (WKB), so a reused layer is the one slicing would give.
        """
        if not self._reuse or i == 0 or i == self.settings.fan_first_layer:
            return None
        skin = self._skins.get(i)
        parts = [b"%d" % (i % 2), shapely.to_wkb(self.outline(i, excluded))]
        if skin is not None:
            parts.append(shapely.to_wkb(skin))
        avoid = self._avoid(i, excluded)
        if avoid is not None:  # travels go around the cancelled bodies
            parts.append(b"avoid" + shapely.to_wkb(avoid))
        return b"|".join(parts)

    def _avoid(self, i: int, excluded: frozenset[int]) -> shapely.Geometry | None:
        """The region of layer ``i``'s travels keep out of: its excluded bodies' outlines,
        grown by :data:`slicer.paths.detour.MARGIN` (None without any)."""
        if not excluded:
            return None
        polys = shapely.get_parts(self._geo.outlines[i])
        if not len(polys):
            return None
        return avoid_region(polys[np.isin(self._geo.bodies(i), list(excluded))])

    def _check(self, i: int) -> int:
        i = int(i)
        if not 0 <= i < self.layer_count:
            raise IndexError(f"layer {i} out of range 0..{self.layer_count - 1}")
        return i

    def _path_bodies(
        self, i: int, paths: Sequence[Path], excluded: frozenset[int]
    ) -> np.ndarray:
        """The body of each of layer ``i``'s ``paths``, (n,) int64: its island's, or for a
        path in no island (support) the body nearest its first point."""
        bodies = self._geo.bodies(i)
        if excluded and len(bodies):
            bodies = bodies[~np.isin(bodies, list(excluded))]
        island = np.array([p.island for p in paths], dtype=np.int64)
        owner = np.full(len(paths), -1, dtype=np.int64)
        inside = island >= 0
        owner[inside] = bodies[island[inside]]
        loose = np.flatnonzero(~inside)
        if len(loose) and len(bodies):
            polys = self._islands(i, excluded)
            firsts = np.array([paths[k].coords[0] for k in loose.tolist()])
            owner[loose] = nearest_body(polys, bodies, firsts, self.outline(i, excluded))
        return owner

    def _islands(self, i: int, excluded: frozenset[int]) -> np.ndarray:
        if not 0 <= i < self.layer_count:
            return _EMPTY
        polys: np.ndarray = shapely.get_parts(self._geo.outlines[i])
        if excluded and len(polys):
            polys = polys[~np.isin(self._geo.bodies(i), list(excluded))]
        return polys

    def _plan_support(self) -> None:
        from slicer.paths.support import support_interfaces, support_regions

        outlines = [self.outline(i) for i in range(self.layer_count)]
        regions = support_regions(outlines, self.settings, self.settings.layer_height)
        interfaces = support_interfaces(
            outlines, regions, self.settings, self.settings.layer_height
        )
        self._support = list(regions)
        self._interface = list(interfaces)


def _private(g: shapely.Geometry | None) -> shapely.Geometry | None:
    """A copy of a shared geometry that one thread may prepare (GEOS prepared
    geometries build their indexes lazily and must not be shared across threads)."""
    if g is None:
        return None
    return private_copy(g)


def _multi(polys: np.ndarray) -> shapely.Geometry:
    """A MultiPolygon of the given polygons (empty when none)."""
    if len(polys) == 0:
        return shapely.MultiPolygon()
    return shapely.multipolygons(polys)


def _cut_model(
    mesh: PlacedMesh, settings: SliceSettings, bed: tuple[float, float, float]
) -> _Geometry:
    """The whole-model pass: layer heights, the faces of each block of layers, object numbers.

    Only the top blocks are cut here (down to the highest layer with area:
    empty layers at the top are not printed); a mesh of several shells whose
    boxes meet is cut whole, on every core (the gyroid ball's 611,498 faces in
    1.45 s instead of 2.2 s), since overlapping shells are one object and
    cavities none.
    """
    tops = layer_tops(mesh.height, settings)
    planes = cut_planes(tops, settings)
    outlines = LazyOutlines(mesh.vertices, mesh.faces, mesh.face_body, planes)
    top = outlines.last_nonempty()
    if top < 0:
        raise ModelError("no layer has a closed outline: the mesh does not enclose a solid")
    # trailing empty layers are not printed
    tops = tops[: top + 1]
    outlines.trim(top + 1)
    if mesh.bodies <= 1:
        body_map = np.zeros(1, dtype=np.int64)
        body_count = 1
    elif _apart(mesh):  # no two shells can overlap or nest: each is one object
        body_map = np.arange(mesh.bodies, dtype=np.int64)
        body_count = mesh.bodies
    else:
        outlines.cut_all(threads=os.cpu_count() or 1)
        raw = [outlines.polygons(i)[1] for i in range(top + 1)]
        body_map = _merge_bodies(mesh.bodies, outlines.report()[0].merged, raw)
        body_count = int(max((body_map[b].max() + 1 for b in raw if len(b)), default=0))
    return _Geometry(
        tops=tops,
        outlines=outlines,
        body_map=body_map,
        bounds=mesh.bounds,
        body_count=body_count,
        bed=bed,
        mesh_warnings=mesh.warnings,
    )


# shells compared pairwise by bounding box up to this many (beyond: cut whole)
_MAX_APART_CHECK = 2000


def _apart(mesh: PlacedMesh) -> bool:
    """Whether the mesh's shells have pairwise disjoint bounding boxes (touching counts as
    meeting), so none can overlap or hold another as a cavity and the whole-model cut
    that numbers objects is not needed. Shells are numbered by first face either way."""
    k = mesh.bodies
    if k > _MAX_APART_CHECK:
        return False
    order = np.argsort(mesh.face_body, kind="stable")
    starts = np.searchsorted(mesh.face_body[order], np.arange(k))  # every shell has faces
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    for j in range(3):
        pts = mesh.vertices[mesh.faces[order, j]]
        lo = np.minimum(lo, np.minimum.reduceat(pts, starts, axis=0))
        hi = np.maximum(hi, np.maximum.reduceat(pts, starts, axis=0))
    overlap = (lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :])
    meet = np.asarray(overlap.all(axis=2))  # (k, k) bool: the boxes of shells i and j meet
    np.fill_diagonal(meet, False)
    return not meet.any()


def _warnings(geo: _Geometry) -> list[str]:
    """The mesh repairs, then what the outline stage fixed in the layers cut so far."""
    report, empty = geo.outlines.report()
    warnings = list(geo.mesh_warnings)
    if report.closed or report.dropped:
        warnings.append(
            f"open outlines in {len(report.gap_layers)} layers: closed {report.closed} gaps"
            + (f", dropped {report.dropped} open pieces" if report.dropped else "")
        )
    if report.merged:
        shells = {b for pair in report.merged for b in pair}
        warnings.append(f"{len(shells)} bodies overlapped: united, printed as one")
    if report.repaired_layers:
        warnings.append(
            "self-intersecting or overlapping outlines made valid in "
            f"{len(report.repaired_layers)} layers"
        )
    if empty:
        warnings.append(f"{empty} layers have no area and print nothing")
    return warnings


def _merge_bodies(
    count: int, merged: set[tuple[int, int]], layers: list[np.ndarray]
) -> np.ndarray:
    """Map mesh shells to objects 0..k-1 (``layers``: the shell of each polygon, per layer).

    Overlapping shells join; shells that own no polygon (cavities) vanish.
    """
    parent = np.arange(max(count, 1))
    for a, b in sorted(merged):
        ra, rb = a, b
        while parent[ra] != ra:
            ra = parent[ra]
        while parent[rb] != rb:
            rb = parent[rb]
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = parent.copy()
    for k in range(len(roots)):
        r = k
        while parent[r] != r:
            r = parent[r]
        roots[k] = r
    used = sorted({int(roots[b]) for body in layers for b in np.unique(body)})
    rank = np.zeros(len(roots), dtype=np.int64)
    for j, r in enumerate(used):
        rank[r] = j
    return rank[roots]
