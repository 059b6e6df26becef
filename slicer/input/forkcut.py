"""Outline blocks cut in a forked process beside this one, sent back as WKB.

Cutting a block is numpy and shapely calls with Python between them: two
threads cutting at once take turns on the interpreter lock (a lattice's 120 ms
cut took 0.18 s on two threads with the first layers sliced beside them), where
a forked process runs on its own core. :class:`CutAway` forks a child that cuts
the blocks left from the top down while this process goes on with its own work
(the first layers, which need the bottom blocks); then this process cuts from
the bottom up until the two meet, and keeps the child's blocks. Which blocks
each has taken is one flag a block in shared memory, set before a block is
begun: the two can at worst both cut the block where they meet, which gives the
same polygons. The child packs the polygons as WKB (exact: the same doubles
come back) with each polygon's body and each block's repair report. A block's
outlines do not depend on where they are cut, so the bytes are the same; a
child that fails leaves its blocks to be cut here.
"""

from __future__ import annotations

import contextlib
import gc
import mmap
import os
import pickle
import signal
import struct
import threading
from collections.abc import Callable, Sequence

import numpy as np
import shapely

from slicer.forkslice import write_all
from slicer.input.lazycut import Polygons

_LENGTH = struct.Struct("<q")  # bytes of one packed block that follow


class CutAway:
    """The blocks ``todo`` (ascending) cut by ``cut(b)``: in a forked child from the
    top down from now on, here from the bottom up in :meth:`meet`; every block is
    given to ``keep(b, polygons)`` (in the thread calling :meth:`meet`).

    The first ``reserved`` blocks are left to this process (the work it does
    meanwhile needs them); ``done(b)`` says a block is had already (cut here
    meanwhile), so :meth:`meet` does not cut it again. Needs ``os.fork``; only
    where forking is safe (no other thread of this process holding a lock the
    child needs).
    """

    def __init__(
        self, todo: Sequence[int], cut: Callable[[int], Polygons],
        keep: Callable[[int, Polygons], None], done: Callable[[int], bool], reserved: int = 0,
    ) -> None:
        self._todo = list(todo)
        self._cut = cut
        self._keep = keep
        self._done = done
        self._taken = mmap.mmap(-1, max(1, len(self._todo)))  # shared with the child
        self._reserved = min(reserved, len(self._todo))
        for k in range(self._reserved):
            self._taken[k] = 1
        self._records: list[bytes] = []
        self._met = False
        read_end, write_end = os.pipe()
        gc.freeze()  # the parent's objects stay out of the child's collections: fewer pages
        try:
            pid = os.fork()
        finally:
            gc.unfreeze()
        if pid == 0:  # the child: never returns
            os.close(read_end)
            self._work(write_end)
        os.close(write_end)
        self.pid = pid
        self._reader = threading.Thread(target=self._read, args=(read_end,), daemon=True,
                                        name=f"cut-{pid}")
        self._reader.start()

    def meet(self) -> None:
        """Cut here, from the bottom up, the blocks the child has not begun; wait for it
        and keep its blocks; cut here the blocks it failed to send."""
        if self._met:
            return
        try:
            for k, b in enumerate(self._todo):
                if self._taken[k] and k >= self._reserved:
                    break  # the child has it, and every block above
                self._taken[k] = 1
                if not self._done(b):
                    self._keep(b, self._cut(b))
        except BaseException:
            self.close()  # the child would go on cutting every block below it
            raise
        self._met = True
        self._reader.join()
        _, status = os.waitpid(self.pid, 0)
        sent = set()
        if os.waitstatus_to_exitcode(status) == 0:
            with contextlib.suppress(Exception):  # unreadable: cut here below
                for record in self._records:
                    for b, polygons in unpack(record).items():
                        self._keep(b, polygons)
                        sent.add(b)
        for b in self._todo:
            if b not in sent and not self._done(b):
                self._keep(b, self._cut(b))

    def close(self) -> None:
        """End the child without its blocks (when :meth:`meet` will not be called)."""
        if self._met:
            return
        self._met = True
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)
        self._reader.join()
        os.waitpid(self.pid, 0)

    def _work(self, pipe: int) -> None:
        """In the child: cut the blocks not taken, top down, sending each; exit."""
        code = 1
        try:
            for k in range(len(self._todo) - 1, -1, -1):
                if self._taken[k]:
                    break  # this process has it, and every block below
                self._taken[k] = 1
                b = self._todo[k]
                data = pack({b: self._cut(b)})
                write_all(pipe, _LENGTH.pack(len(data)) + data)
            code = 0
        finally:
            os._exit(code)

    def _read(self, fd: int) -> None:
        """On a thread here: the child's records as they come (the pipe never fills);
        a record cut off ends the reading, and the blocks not read are cut here."""
        with open(fd, "rb") as pipe:
            while len(head := pipe.read(_LENGTH.size)) == _LENGTH.size:
                (length,) = _LENGTH.unpack(head)
                record = pipe.read(length)
                if len(record) != length:
                    return
                self._records.append(record)

def pack(blocks: dict[int, Polygons]) -> bytes:
    """Blocks of polygons as bytes: the polygons' WKB in one vectorised call."""
    ids = list(blocks)
    layers = [len(blocks[b][0]) for b in ids]
    counts = [len(p) for b in ids for p in blocks[b][0]]
    polygons = [p for b in ids for p in blocks[b][0]]
    bodies = [body for b in ids for body in blocks[b][1]]
    flat = np.concatenate(polygons) if polygons else np.empty(0, dtype=object)
    return pickle.dumps(
        (ids, layers, counts, shapely.to_wkb(flat).tolist(),
         np.concatenate(bodies) if bodies else np.empty(0, dtype=np.int64),
         [blocks[b][2] for b in ids]),
        protocol=pickle.HIGHEST_PROTOCOL,
    )


def unpack(data: bytes) -> dict[int, Polygons]:
    """The blocks :func:`pack` packed, polygons equal to the originals bit for bit."""
    ids, layers, counts, wkb, bodies, reports = pickle.loads(data)
    flat = shapely.from_wkb(np.array(wkb, dtype=object))
    cuts = np.cumsum([0, *counts]).tolist()
    out: dict[int, Polygons] = {}
    layer = 0
    for b, count, report in zip(ids, layers, reports, strict=True):
        polys = tuple(flat[cuts[k]:cuts[k + 1]] for k in range(layer, layer + count))
        body = tuple(bodies[cuts[k]:cuts[k + 1]] for k in range(layer, layer + count))
        out[b] = (polys, body, report)
        layer += count
    return out
