"""Outline blocks cut in forked processes beside this one, sent back as WKB.

Cutting a block is numpy and shapely calls with Python between them: two
threads cutting at once take turns on the interpreter lock (a lattice's 120 ms
cut took 0.18 s on two threads with the first layers sliced beside them), where
a forked process runs on its own core. Each child cuts its share of the blocks
left (shares balanced by the faces each block holds), packs the polygons as
WKB (exact: the same doubles come back) with each polygon's body and each
block's repair report, writes them to a pipe and exits; this process cuts
its own share meanwhile, then reads the others' back. A block's outlines do
not depend on where they are cut, so the bytes are the same. A child that fails
leaves its share to be cut here.
"""

from __future__ import annotations

import contextlib
import gc
import os
import pickle
import threading
from collections.abc import Callable, Sequence

import numpy as np
import shapely

from slicer.lazycut import Polygons


def balanced_shares(blocks: Sequence[int], weight: np.ndarray, shares: int) -> list[list[int]]:
    """``blocks`` in ``shares`` lists of about equal total ``weight`` (one number per
    block, e.g. its faces), each list ascending: the heaviest block first to the
    lightest share."""
    totals = [0.0] * shares
    out: list[list[int]] = [[] for _ in range(shares)]
    for k in np.argsort(-np.asarray(weight, dtype=np.float64), kind="stable").tolist():
        lightest = totals.index(min(totals))
        out[lightest].append(blocks[k])
        totals[lightest] += float(weight[k])
    return [sorted(share) for share in out]


def cut_in_processes(
    shares: Sequence[Sequence[int]],
    cut: Callable[[int], Polygons],
    keep: Callable[[int, Polygons], None],
) -> None:
    """Cut ``shares[0]`` here with ``cut(b)`` and every other share in a forked child;
    ``keep(b, polygons)`` is given each block, here in the calling thread, in no
    set order. A child's error, or its end before sending, has its blocks cut
    here instead (the error itself is raised by that cut, if it recurs)."""
    children = [_Child.fork(share, cut) for share in shares[1:] if share]
    try:
        for b in shares[0]:
            keep(b, cut(b))
    finally:
        for child in children:
            for b, polygons in child.collect(cut):
                keep(b, polygons)


class _Child:
    """A forked process cutting a share of blocks, and the thread reading its pipe."""

    def __init__(self, pid: int, share: Sequence[int], fd: int) -> None:
        self.pid = pid
        self.share = list(share)
        self._chunks: list[bytes] = []
        self._reader = threading.Thread(target=self._read, args=(fd,), daemon=True,
                                        name=f"cut-{pid}")
        self._reader.start()

    @classmethod
    def fork(cls, share: Sequence[int], cut: Callable[[int], Polygons]) -> _Child:
        read_end, write_end = os.pipe()
        gc.freeze()  # the parent's objects stay out of the child's collections: fewer pages
        try:
            pid = os.fork()
        finally:
            gc.unfreeze()
        if pid == 0:  # the child: never returns
            code = 1
            try:
                os.close(read_end)
                _write_all(write_end, pack({b: cut(b) for b in share}))
                code = 0
            finally:
                os._exit(code)
        os.close(write_end)
        return cls(pid, share, read_end)

    def _read(self, fd: int) -> None:
        with open(fd, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 20):
                self._chunks.append(chunk)

    def collect(self, cut: Callable[[int], Polygons]) -> list[tuple[int, Polygons]]:
        """The child's blocks, once it has ended; its share cut with ``cut`` here when
        it failed or sent what cannot be read."""
        self._reader.join()
        _, status = os.waitpid(self.pid, 0)
        if os.waitstatus_to_exitcode(status) == 0:
            with contextlib.suppress(Exception):
                return list(unpack(b"".join(self._chunks)).items())
        return [(b, cut(b)) for b in self.share]


def pack(blocks: dict[int, Polygons]) -> bytes:
    """Blocks of polygons as bytes: the polygons' WKB in one vectorised call."""
    ids = list(blocks)
    layers = [len(blocks[b][0]) for b in ids]
    counts = [len(p) for b in ids for p in blocks[b][0]]
    polygons = [p for b in ids for p in blocks[b][0]]
    bodies = [body for b in ids for body in blocks[b][1]]
    flat = np.concatenate(polygons) if polygons else np.empty(0, dtype=object)
    wkb = shapely.to_wkb(flat)
    lengths = np.fromiter((len(w) for w in wkb), dtype=np.int64, count=len(wkb))
    return pickle.dumps(
        (ids, layers, counts, b"".join(wkb.tolist()), lengths,
         np.concatenate(bodies) if bodies else np.empty(0, dtype=np.int64),
         [blocks[b][2] for b in ids]),
        protocol=pickle.HIGHEST_PROTOCOL,
    )


def unpack(data: bytes) -> dict[int, Polygons]:
    """The blocks :func:`pack` packed, polygons equal to the originals bit for bit."""
    ids, layers, counts, joined, lengths, bodies, reports = pickle.loads(data)
    ends = np.cumsum(lengths).tolist()
    starts = [0, *ends[:-1]]
    wkb = np.empty(len(ends), dtype=object)
    wkb[:] = [joined[a:b] for a, b in zip(starts, ends, strict=True)]
    flat = shapely.from_wkb(wkb)
    cuts = np.cumsum([0, *counts]).tolist()
    out: dict[int, Polygons] = {}
    layer = 0
    for b, count, report in zip(ids, layers, reports, strict=True):
        polys = tuple(flat[cuts[k]:cuts[k + 1]] for k in range(layer, layer + count))
        body = tuple(bodies[cuts[k]:cuts[k + 1]] for k in range(layer, layer + count))
        out[b] = (polys, body, report)
        layer += count
    return out


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]
