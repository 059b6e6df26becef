"""A model's plan in a process of its own, which slices its layers and ends with the job.

A long-running host that slices in its own threads keeps what slicing leaves in
its C heaps: freed chunks between the few allocations that outlive a layer, which
no trim can hand back. Slicing each job's layers in a child process, ended with
the job, returns all of it to the system at once.

The child is a fresh interpreter (multiprocessing's ``spawn``): it never inherits
the parent's threads or locks, and nothing of it stays once the job ended. It
imports the slicer (some 0.5 s) and builds the job's plan from the file, as the
parent did: same file, same settings, the same layers byte for byte. A fork
server with the slicer preloaded would start children sooner, but it stays
resident between jobs (about 50 MB), for a gain the parent covers anyway by
slicing the first layers itself.
"""

from __future__ import annotations

import concurrent.futures
import hashlib
import itertools
import logging
import multiprocessing
import multiprocessing.connection
import os
import threading
from collections.abc import Callable
from typing import Any

from slicer.output.gcode import LayerCode
from slicer.plan import SlicePlan
from slicer.settings import SliceSettings

log = logging.getLogger("slicer.planprocess")

CLOSE_WAIT_S = 5.0  # a terminated child's time to end before it is killed


class PlanProcessGone(RuntimeError):
    """The child slicing the job's layers is no longer there (closed, or it died)."""


class PlanProcess:
    """A child process holding the plan of ``path`` with ``settings`` on ``bed``.

    :meth:`call` runs ``function(plan, *args)`` there, where ``plan`` is the plan with
    the settings given (the same geometry, :meth:`SlicePlan.with_settings`), on up to
    ``threads`` threads of the child at once; the result comes back pickled. Safe to
    call from any thread. :attr:`ready` is set once the child's plan is built.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        settings: SliceSettings,
        bed: tuple[float, float, float],
        threads: int = 2,
        sha256: str | None = None,
    ) -> None:
        """``sha256``: the file's hash as the parent read it; a child that reads other
        bytes (the file changed since) builds no plan and says so."""
        context = multiprocessing.get_context("spawn")
        mine, theirs = context.Pipe()
        self._process = context.Process(
            target=_serve,
            args=(theirs, os.fspath(path), settings, bed, max(1, threads), sha256),
            name="hostd-plan", daemon=True,
        )
        self._process.start()
        theirs.close()
        self._conn: multiprocessing.connection.Connection = mine
        self._send_lock = threading.Lock()
        self._lock = threading.Lock()
        self._pending: dict[int, concurrent.futures.Future[Any]] = {}
        self._ids = itertools.count()
        self._gone: str | None = None  # why the child is gone, once it is
        self.ready = threading.Event()
        self._settled = threading.Event()  # ready, or gone
        self._reader = threading.Thread(target=self._read, name="hostd-plan-reader",
                                        daemon=True)
        self._reader.start()

    @property
    def pid(self) -> int | None:
        """The child's process id."""
        pid: int | None = self._process.pid
        return pid

    @property
    def gone(self) -> str | None:
        """Why the child is gone (closed, died, its plan failed), or None while it serves."""
        return self._gone

    def wait_ready(self, timeout_s: float | None = None) -> bool:
        """Wait until the child's plan is built; False if the child is gone first (or
        after ``timeout_s``)."""
        self._settled.wait(timeout_s)
        return self.ready.is_set() and self._gone is None

    def call(self, function: Callable[..., Any], settings: SliceSettings,
             *args: Any) -> concurrent.futures.Future[Any]:
        """``function(plan, *args)`` in the child, ``plan`` having ``settings``; the
        future fails with :class:`PlanProcessGone` if the child ends first."""
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        with self._lock:
            if self._gone is not None:
                raise PlanProcessGone(self._gone)
            number = next(self._ids)
            self._pending[number] = future
        try:
            with self._send_lock:
                self._conn.send((number, function, settings, args))
        except (OSError, ValueError) as exc:  # the pipe closed under us
            self._end(f"the slicing process is gone ({exc})")
        except Exception:  # a call that does not pickle: nothing was sent
            with self._lock:
                self._pending.pop(number, None)
            raise
        return future

    def layer_code(self, settings: SliceSettings, layer: int, excluded: frozenset[int],
                   forget_below: int = 0) -> LayerCode:
        """Layer ``layer``'s code made in the child (waits for it); the child's plans
        let go of the layers below ``forget_below``."""
        code: LayerCode = self.call(_layer_code, settings, layer, excluded,
                                    forget_below).result()
        return code

    def _read(self) -> None:
        """Hand each answer to its future until the child's end of the pipe closes."""
        why = "the slicing process ended"
        try:
            while True:
                number, ok, value = self._conn.recv()
                if number == "ready":
                    self.ready.set()
                    self._settled.set()
                    continue
                if number == "failed":
                    why = f"the slicing process could not build the plan: {value}"
                    break
                with self._lock:
                    future = self._pending.pop(number, None)
                if future is None:
                    continue
                if ok:
                    future.set_result(value)
                else:
                    future.set_exception(value)
        except (EOFError, OSError):
            pass
        self._end(why)

    def _end(self, why: str) -> None:
        """Fail every call still waiting: the child will not answer them."""
        with self._lock:
            if self._gone is None:
                self._gone = why
            pending, self._pending = self._pending, {}
        self._settled.set()
        for future in pending.values():
            if not future.done():
                future.set_exception(PlanProcessGone(self._gone))

    def close(self) -> None:
        """End the child (calls still waiting fail) and wait for it to be gone: at
        once, as nothing it would still make is wanted (it may be importing yet)."""
        with self._lock:
            if self._gone is None:
                self._gone = "the slicing process was closed"
        if self._process.is_alive():
            self._process.terminate()
        self._process.join(CLOSE_WAIT_S)
        if self._process.is_alive():
            log.warning("slicing process %s did not end: killed", self._process.pid)
            self._process.kill()
            self._process.join(CLOSE_WAIT_S)
        self._reader.join(CLOSE_WAIT_S)
        self._conn.close()
        self._end(self._gone)


def plan_warnings(plan: SlicePlan) -> list[str]:
    """The plan's :attr:`SlicePlan.warnings` (a function, to be called in a child)."""
    return plan.warnings


# in a child: its plans, one per settings the job's layers were asked with
_CHILD_PLANS: dict[SliceSettings, SlicePlan] = {}
_CHILD_PLANS_LOCK = threading.Lock()


def _layer_code(plan: SlicePlan, layer: int, excluded: frozenset[int],
                forget_below: int) -> LayerCode:
    """In the child: one layer's code, its plans letting go of the layers far below."""
    if forget_below > 0:
        with _CHILD_PLANS_LOCK:
            every = list(_CHILD_PLANS.values())
        for each in every:
            each.forget_before(forget_below)
    return plan.layer_code(layer, excluded)


def _file_sha256(path: str) -> str:
    """The SHA-256 of the file's bytes, as hex."""
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _serve(conn: multiprocessing.connection.Connection, path: str, settings: SliceSettings,
           bed: tuple[float, float, float], threads: int, sha256: str | None) -> None:
    """The child: build the plan (from the bytes the parent hashed, ``sha256``, read
    the same before and after), then answer calls on ``threads`` threads until told
    to stop (None) or the parent's end of the pipe closes."""
    try:
        if sha256 is not None and _file_sha256(path) != sha256:
            raise ValueError("the file changed since the job took it")
        base = SlicePlan.from_file(path, settings, bed)
        if sha256 is not None and _file_sha256(path) != sha256:
            raise ValueError("the file changed while its plan was built")
    except Exception as exc:  # the parent slices in its own threads instead
        conn.send(("failed", False, f"{type(exc).__name__}: {exc}"))
        return
    _CHILD_PLANS[settings] = base
    send_lock = threading.Lock()

    def plan_with(wanted: SliceSettings) -> SlicePlan:
        with _CHILD_PLANS_LOCK:
            plan = _CHILD_PLANS.get(wanted)
            if plan is None:
                plan = _CHILD_PLANS[wanted] = base.with_settings(wanted)
        return plan

    def answer(number: int, function: Callable[..., Any], wanted: SliceSettings,
               args: tuple[Any, ...]) -> None:
        try:
            reply: tuple[Any, bool, Any] = (number, True, function(plan_with(wanted), *args))
        except Exception as exc:
            reply = (number, False, exc)
        with send_lock:
            try:
                conn.send(reply)
            except Exception as exc:  # an answer that does not pickle
                conn.send((number, False, RuntimeError(f"{type(exc).__name__}: {exc}")))

    conn.send(("ready", True, None))
    with concurrent.futures.ThreadPoolExecutor(threads, thread_name_prefix="plan") as pool:
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):
                break
            if message is None:
                break
            pool.submit(answer, *message)
