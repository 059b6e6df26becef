"""Layer outlines cut on demand, a block of layers at a time, each block once (thread-safe).

The whole-model pass only finds which faces cross which layers and buckets
the faces by block of layers; a block's outlines (cut, chained, nested) are
made when one of its layers is first asked for. A layer's outline does not
depend on which other layers are cut with it, so the bytes are the same in
any order, from any thread or forked process.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely

from slicer.input.outline import GapReport, OutlineTolerances, build_layers
from slicer.input.section import cut_block, face_layer_ranges

if TYPE_CHECKING:
    from slicer.input.forkcut import CutAway

# per layer of a block its polygons (p,) object and their bodies (p,) int64, and
# what its cut repaired
Polygons = tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], GapReport]
_EMPTY = np.empty(0, dtype=object)
_NO_BODY = np.empty(0, dtype=np.int64)
# estimated seconds per block left from which :meth:`LazyOutlines.cut_threads`
# says more than one thread: light blocks are mostly Python between short array
# calls, and two threads then take turns on the interpreter lock. A 450-layer
# tower (2.3 ms a block) cut its 29 blocks in 0.056 s on one thread and in
# 0.086-0.099 s on two; a cone on a sphere (6 ms) 0.030 s against 0.032-0.057 s;
# a plate of 16 parts (8 ms) 0.031 s against 0.027 s; Benchy (25 ms) 0.25 s
# against 0.17 s
_THREADS_WORTH = 0.007
# layers per block: 16, or 64 where a layer crosses few faces. A block's cut is some
# forty array calls whatever its size, about 1 ms on light layers: the 450-layer
# tower (104 face crossings a layer) cut in 62 ms in blocks of 16 and in 44 ms in
# blocks of 64, a bracket (116) in 29 and 22 ms, a plate with holes (131) in 22 and
# 17 ms; from some 300 crossings a layer (a cone on a sphere, a lattice) the array
# work is most of a block's time and bigger blocks gained nothing or lost a little
BLOCK = 16
LIGHT_BLOCK = 64
_LIGHT_CROSSINGS = 200  # face crossings per layer, at most, for LIGHT_BLOCK


@dataclass(frozen=True)
class _Block:
    """One block's outlines: per layer (MultiPolygon, raw body per polygon), and its report."""

    outlines: tuple[shapely.Geometry, ...]
    polygons: tuple[np.ndarray, ...]
    bodies: tuple[np.ndarray, ...]
    report: GapReport


class LazyOutlines:
    """Outlines of ``len(planes)`` layers, cut in blocks of ``block`` layers on first use
    (by default :data:`BLOCK`, or :data:`LIGHT_BLOCK` where the layers cross few faces).

    ``vertices`` (v, 3) float64 mm, ``faces`` (f, 3) int64 and ``face_body``
    (f,) int64 of the placed mesh; ``planes`` (m,) float64 mm, where each
    layer is cut. Indexing (``outlines[i]``, ``outlines[a:b]``) gives
    MultiPolygons, as the array of a full cut would; ``len`` is the number of
    layers printed (:meth:`trim` drops empty layers at the top).
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        face_body: np.ndarray,
        planes: np.ndarray,
        block: int | None = None,
    ) -> None:
        self._vertices = vertices
        self._faces = faces
        self._face_body = face_body
        self._planes = planes
        self._count = len(planes)
        self._tol = OutlineTolerances()
        lo, hi = face_layer_ranges(vertices[:, 2], faces, planes)
        self._block = block if block is not None else block_layers(lo, hi, len(planes))
        block = self._block
        self._lo, self._hi, self._members, self._offsets = _bucket(lo, hi, block, len(planes))
        self._lock = threading.Lock()
        self._blocks: dict[int, _Block] = {}
        self._busy: dict[int, threading.Lock] = {}
        self._cut_seconds = 0.0  # summed over the blocks cut so far (any thread)
        # blocks let go (forget_before): their report, and which of their layers are empty
        self._forgotten: dict[int, tuple[GapReport, tuple[bool, ...]]] = {}

    # ---- sequence of MultiPolygons --------------------------------------
    def __len__(self) -> int:
        return self._count

    def __getitem__(self, key: int | slice) -> shapely.Geometry | np.ndarray:
        if isinstance(key, slice):
            idx = range(*key.indices(self._count))
            out = np.empty(len(idx), dtype=object)
            out[:] = [self.outline(i) for i in idx]
            return out
        return self.outline(int(key))

    # ---- per layer ------------------------------------------------------
    def outline(self, i: int) -> shapely.Geometry:
        """Layer ``i``'s outline, a MultiPolygon (empty when the layer has no area)."""
        b = self._get(i // self._block)
        return b.outlines[i - (i // self._block) * self._block]

    def polygons(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Layer ``i``'s polygons (p,) object and the mesh shell of each (p,) int64."""
        b = self._get(i // self._block)
        k = i - (i // self._block) * self._block
        return b.polygons[k], b.bodies[k]

    # ---- whole model ----------------------------------------------------
    def last_nonempty(self) -> int:
        """Index of the highest layer with area (-1 when none), cutting from the top down."""
        for b in range((len(self._planes) - 1) // self._block, -1, -1):
            block = self._get(b)
            full = [k for k, p in enumerate(block.polygons) if len(p)]
            if full:
                return b * self._block + full[-1]
        return -1

    def trim(self, count: int) -> None:
        """Print only the first ``count`` layers (the ones above have no area)."""
        self._count = count

    def cut_threads(self, threads: int) -> int:
        """How many threads :meth:`cut_all` would cut the blocks left on, at most
        ``threads``: one when fewer than two blocks are left or the blocks left are
        light, an estimated :data:`_THREADS_WORTH` or less per 16 layers
        (:meth:`cut_estimate`)."""
        left = self._block_count() - len(self._cut_blocks())
        if threads <= 1 or left < 2:
            return 1
        per_block = self.cut_estimate() / left
        return 1 if per_block < _THREADS_WORTH * self._block / BLOCK else threads

    def cut_estimate(self) -> float:
        """Estimated seconds to cut the blocks left on one thread: the mean time of the
        blocks cut so far, scaled by the faces the blocks left have against them (a
        sphere's pole is lighter than its middle); inf when none is cut yet."""
        with self._lock:
            count = self._block_count()
            done = self._cut_blocks()
            left = [b for b in range(count) if b not in self._blocks and b not in self._forgotten]
            seconds = self._cut_seconds
        if not left:
            return 0.0
        if not done:
            return float("inf")
        faces = np.diff(self._offsets)
        cut_faces = max(int(faces[done].sum()), 1)
        return seconds / cut_faces * float(faces[left].sum())

    def _cut_blocks(self) -> list[int]:
        """The printed blocks cut so far (held, or let go by :meth:`forget_before`)."""
        count = self._block_count()
        return [b for b in {*self._blocks, *self._forgotten} if b < count]

    def forget_before(self, layer: int) -> int:
        """Let go of the blocks all of whose layers lie below ``layer``, keeping what
        their cut repaired (:meth:`report`); a layer of them asked for again is cut
        again, the same. A print that goes up layer by layer holds a window of blocks,
        not the whole model. Returns how many blocks were let go."""
        with self._lock:
            gone = [b for b in self._blocks if (b + 1) * self._block <= layer]
            for b in gone:
                block = self._blocks.pop(b)
                self._busy.pop(b, None)
                self._forgotten[b] = (block.report, tuple(not len(p) for p in block.polygons))
        return len(gone)

    @property
    def held_blocks(self) -> int:
        """Blocks of outlines held now."""
        with self._lock:
            return len(self._blocks)

    def cut_all(self, threads: int = 1) -> None:
        """Cut every block not cut yet, on up to ``threads`` threads.

        Most of a heavy block's cut is numpy sorting and shapely array work,
        which release the interpreter lock, so two threads overlap well; light
        blocks are cut on this thread alone (:meth:`cut_threads`). The outlines
        are the same however many threads cut them.
        """
        threads = self.cut_threads(threads)
        with self._lock:
            todo = [b for b in range(self._block_count())
                    if b not in self._blocks and b not in self._forgotten]
        if threads <= 1:
            for b in todo:
                self._get(b)
            return
        queue = iter(todo)
        take = threading.Lock()
        failed: list[BaseException] = []

        def work() -> None:
            while not failed:
                with take:
                    b = next(queue, None)
                if b is None:
                    return
                try:
                    self._get(b)
                except BaseException as exc:  # re-raised in the calling thread
                    failed.append(exc)

        pool = [threading.Thread(target=work, name=f"cut-{k}") for k in range(threads)]
        for t in pool:
            t.start()
        for t in pool:
            t.join()
        if failed:
            raise failed[0]

    def cut_away(self, reserved_layers: int = 0) -> CutAway | None:
        """Start cutting the blocks left in a forked process, from the top down, while
        this one goes on (:class:`slicer.input.forkcut.CutAway`; its ``meet`` cuts the rest
        here and keeps them all); the blocks of the first ``reserved_layers`` layers
        are left to this process. None with fewer than two blocks left or no
        ``fork``. Only where forking is safe: no other thread of this process may
        hold a lock the child needs."""
        with self._lock:
            todo = [b for b in range(self._block_count())
                    if b not in self._blocks and b not in self._forgotten]
        if len(todo) < 2 or not hasattr(os, "fork"):
            return None
        from slicer.input.forkcut import CutAway

        reserved = -(-reserved_layers // self._block)
        return CutAway(todo, self._cut_polygons, self._keep, self._has,
                       sum(1 for b in todo if b < reserved))

    def _has(self, b: int) -> bool:
        with self._lock:
            return b in self._blocks

    def _keep(self, b: int, polygons: Polygons) -> None:
        """Hold block ``b``, cut elsewhere (the first one kept stays)."""
        block = _block(polygons)
        with self._lock:
            self._blocks.setdefault(b, block)

    def report(self) -> tuple[GapReport, int]:
        """What the blocks cut so far had to fix, and how many printed layers are empty."""
        with self._lock:
            blocks = {b: (block.report, tuple(not len(p) for p in block.polygons))
                      for b, block in self._blocks.items()}
            blocks = {**self._forgotten, **blocks}
        total = GapReport()
        empty = 0
        for b, (report, empties) in sorted(blocks.items()):
            total.closed += report.closed
            total.dropped += report.dropped
            total.gap_layers |= report.gap_layers
            total.repaired_layers |= report.repaired_layers
            total.merged |= report.merged
            lo = b * self._block
            empty += sum(1 for k, none in enumerate(empties) if lo + k < self._count and none)
        return total, empty

    # ---- internals ------------------------------------------------------
    def _block_count(self) -> int:
        return (self._count + self._block - 1) // self._block

    def _get(self, b: int) -> _Block:
        with self._lock:
            done = self._blocks.get(b)
            if done is not None:
                return done
            busy = self._busy.setdefault(b, threading.Lock())
        with busy:
            with self._lock:
                done = self._blocks.get(b)
            if done is None:
                started = time.perf_counter()
                done = self._cut(b)
                with self._lock:
                    self._blocks[b] = done
                    self._cut_seconds += time.perf_counter() - started
        return done

    def _cut(self, b: int) -> _Block:
        """Cut, chain and nest the layers of block ``b``."""
        return _block(self._cut_polygons(b))

    def _cut_polygons(self, b: int) -> Polygons:
        """The polygons of block ``b``'s layers (cut, chained, nested), their bodies and
        what the cut repaired."""
        first = b * self._block
        last = min(first + self._block, len(self._planes))
        faces = self._members[self._offsets[b] : self._offsets[b + 1]]  # ascending face index
        chains = cut_block(
            self._vertices, self._faces[faces], self._planes,
            self._lo[faces], self._hi[faces], first, last,
        )  # fmt: skip
        report = GapReport()
        layers = build_layers(
            chains, self._face_body[faces], np.arange(first, last), self._tol, report
        )
        polys = []
        bodies = []
        for i in range(first, last):
            p, body = layers.get(i, (_EMPTY, _NO_BODY))
            polys.append(p)
            bodies.append(body)
        return tuple(polys), tuple(bodies), report


def _block(polygons: Polygons) -> _Block:
    """A block of its layers' polygons, bodies and report, with each layer's outline."""
    polys, bodies, report = polygons
    outlines = tuple(shapely.MultiPolygon() if len(p) == 0 else shapely.multipolygons(p)
                     for p in polys)
    return _Block(outlines, polys, bodies, report)


def block_layers(lo: np.ndarray, hi: np.ndarray, layers: int) -> int:
    """Layers per block for faces crossing planes ``[lo, hi)`` (from
    :func:`slicer.input.section.face_layer_ranges`) of ``layers`` planes: :data:`LIGHT_BLOCK`
    when a layer crosses :data:`_LIGHT_CROSSINGS` faces or fewer on average, else
    :data:`BLOCK`."""
    crossings = int(np.clip(hi - lo, 0, None).sum())
    return LIGHT_BLOCK if crossings <= _LIGHT_CROSSINGS * max(layers, 1) else BLOCK


def _bucket(
    lo: np.ndarray, hi: np.ndarray, block: int, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Faces of each block of layers: (lo, hi, members, offsets).

    A face crossing planes ``[lo, hi)`` is listed in every block it reaches;
    block ``b``'s faces are ``members[offsets[b]:offsets[b + 1]]``, ascending.
    """
    np.minimum(lo, n, out=lo)
    np.minimum(hi, n, out=hi)
    crossing = np.flatnonzero(hi > lo)
    b0 = lo[crossing] // block
    span = (hi[crossing] - 1) // block
    span -= b0
    span += 1
    blocks = (n + block - 1) // block
    if len(crossing) and int(span.max()) == 1:  # every face in one block (the usual case)
        blk = b0
    else:
        face = np.repeat(crossing, span)
        starts = np.cumsum(span) - span
        blk = np.repeat(b0, span) + (np.arange(len(face)) - np.repeat(starts, span))
        crossing = face
        del face, starts
    del b0, span
    counts = np.bincount(blk, minlength=blocks)
    # sorted by block, faces ascending within each: one plain sort of the block
    # number packed above the position (much faster than a stable argsort)
    shift = max(1, (len(blk) - 1).bit_length())
    key = blk.astype(np.int64) << shift
    del blk
    key |= np.arange(len(key), dtype=np.int64)
    key.sort()
    key &= (1 << shift) - 1
    members = crossing[key]
    del key, crossing
    offsets = np.concatenate(([0], np.cumsum(counts)))
    return lo, hi, members, offsets.astype(np.int64)
