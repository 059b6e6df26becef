"""The control socket server: the daemon side of the JSON-lines protocol in :mod:`hostd.api`."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import json
import logging
import os
import socket
import stat
from pathlib import Path
from typing import Any

from hostd.api import COMMANDS, accepted, refused
from hostd.publishing.status import CommandError, Controller, StatusHub

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 1 << 20  # a request line longer than this closes the connection
_SUN_PATH_MAX = 107  # bytes in sockaddr_un.sun_path, less the terminating NUL
_SERVED_HERE = frozenset({"status", "subscribe"})


class ControlSocketError(OSError):
    """The control socket cannot be created (path in use, too long, or not a socket)."""


def _claim_path(path: Path) -> None:
    """Make ``path`` free for a new socket: remove a stale socket, refuse anything else."""
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise ControlSocketError(f"{path} exists and is not a socket; not replacing it")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(str(path))
        except OSError as exc:
            if exc.errno not in (errno.ECONNREFUSED, errno.ENOENT):
                raise ControlSocketError(f"cannot probe {path}: {exc}") from exc
        else:
            raise ControlSocketError(f"another daemon is serving {path}")
    path.unlink(missing_ok=True)
    log.info("removed stale control socket %s", path)


def _bind_private(path: Path) -> socket.socket:
    """A listening Unix stream socket at ``path`` with mode 0600, set before ``listen``.

    It is bound and listening under a temporary name beside ``path``, then linked
    into place, so a client that sees the file can connect: bound at ``path``
    itself, a client connecting between ``bind`` and ``listen`` was refused. A
    ``path`` too close to the length limit for a longer name is bound in place.
    """
    if len(os.fsencode(path)) > _SUN_PATH_MAX:
        raise ControlSocketError(f"socket path too long ({_SUN_PATH_MAX} bytes at most): {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    _claim_path(path)
    aside = path.with_name(f".{path.name}.{os.getpid()}")
    if len(os.fsencode(aside)) > _SUN_PATH_MAX:
        aside = path
    aside.unlink(missing_ok=True)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.bind(str(aside))
        os.chmod(aside, 0o600)  # nobody can connect before listen(), so no window
        sock.listen(64)
        sock.setblocking(False)
        if aside != path:
            os.link(aside, path)  # never over a socket another daemon bound meanwhile
            aside.unlink()
    except OSError as exc:
        sock.close()
        if aside != path:
            aside.unlink(missing_ok=True)
        if isinstance(exc, FileExistsError):
            raise ControlSocketError(f"another daemon is serving {path}") from exc
        raise
    return sock


def _encode(item: dict[str, Any]) -> bytes:
    return (json.dumps(item, separators=(",", ":"), default=str) + "\n").encode()


class _Connection:
    """One client: answers requests in order and, once subscribed, streams status and events."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        hub: StatusHub,
        controller: Controller,
    ) -> None:
        self._reader = reader
        self._writer = writer
        self._hub = hub
        self._controller = controller
        self._subscribed = False

    async def send(self, item: dict[str, Any]) -> None:
        """Write one JSON line (whole, so lines from several tasks never interleave)."""
        self._writer.write(_encode(item))
        await self._writer.drain()

    async def serve(self) -> None:
        """Answer requests until the client hangs up; stream to it once subscribed."""
        streams: list[asyncio.Task[None]] = []
        async with asyncio.TaskGroup() as group:
            try:
                await self._read_requests(group, streams)
            finally:
                for task in streams:  # the streams end with the requests
                    task.cancel()

    async def _read_requests(
        self, group: asyncio.TaskGroup, streams: list[asyncio.Task[None]]
    ) -> None:
        while True:
            try:
                line = await self._reader.readline()
            except ValueError:  # longer than the reader's limit: the stream is out of step
                await self.send(refused(None, None, "request line too long"))
                return
            if not line:
                return
            if not line.strip():
                continue
            reply = await self._answer(line)
            if reply["reply"] == "subscribe" and reply["ok"] and not self._subscribed:
                # reply, then the current snapshot, then every later one; the streams
                # register with the hub before this connection is read again
                self._subscribed = True
                self._writer.write(_encode(reply))
                self._writer.write(_encode({"status": self._hub.current.to_dict()}))
                streams.append(
                    group.create_task(self._stream_status(), name="control-stream-status")
                )
                streams.append(
                    group.create_task(self._stream_events(), name="control-stream-events")
                )
                await asyncio.sleep(0)  # let both streams register with the hub
                await self._writer.drain()
            else:
                await self.send(reply)

    async def _answer(self, line: bytes) -> dict[str, Any]:
        """The reply to one request line; never raises for bad input or refused commands."""
        try:
            request = json.loads(line)
        except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
            return refused(None, None, f"malformed JSON: {exc}")
        except RecursionError:
            return refused(None, None, "malformed JSON: nested too deeply")
        if not isinstance(request, dict):
            return refused(None, None, "a request must be a JSON object")
        cmd = request.get("cmd")
        request_id = request.get("id")
        if not isinstance(cmd, str):
            return refused(None, request_id, 'missing "cmd"')
        if cmd not in COMMANDS:
            return refused(cmd, request_id, f"unknown command {cmd!r}")
        if cmd == "status":
            return accepted(cmd, request_id, {"status": self._hub.current.to_dict()})
        if cmd == "subscribe":
            return accepted(cmd, request_id, {})
        args = {key: value for key, value in request.items() if key not in ("cmd", "id")}
        try:
            result = await self._controller.handle(cmd, args)
        except CommandError as exc:
            return refused(cmd, request_id, str(exc))
        except Exception as exc:  # a controller bug must not take the socket down
            log.exception("control command %s failed", cmd)
            return refused(cmd, request_id, f"internal error: {type(exc).__name__}: {exc}")
        return accepted(cmd, request_id, dict(result or {}))

    async def _stream_status(self) -> None:
        async for snapshot in self._hub.snapshots():
            await self.send({"status": snapshot.to_dict()})

    async def _stream_events(self) -> None:
        async for event in self._hub.events():
            await self.send({"event": event})


async def serve_control(path: Path, hub: StatusHub, controller: Controller) -> None:
    """Serve the control socket at ``path`` until cancelled.

    The socket is created with mode 0600 (a stale socket left by a dead daemon
    is replaced; a live one or any other file is refused with
    :class:`ControlSocketError`) and removed on exit. Each connection speaks
    the JSON-lines protocol of :mod:`hostd.api`: ``status`` and ``subscribe``
    are served from ``hub``; every other command goes to
    ``controller.handle(cmd, args)``.
    """
    path = Path(path)
    sock = _bind_private(path)
    identity = path.stat().st_ino
    try:
        async with asyncio.TaskGroup() as group:

            def on_connect(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
                connection = _Connection(reader, writer, hub, controller)
                group.create_task(_serve_connection(connection, writer), name="control-client")

            server = await asyncio.start_unix_server(on_connect, sock=sock, limit=MAX_LINE_BYTES)
            async with server:
                await server.serve_forever()
    finally:
        sock.close()
        with contextlib.suppress(FileNotFoundError):
            if path.stat().st_ino == identity:  # never remove a newer daemon's socket
                path.unlink()


async def _serve_connection(connection: _Connection, writer: asyncio.StreamWriter) -> None:
    """Serve one client to the end; its failures never reach the server's task group."""
    try:
        await connection.serve()
    except* ConnectionError:
        pass  # the client went away mid-write
    except* Exception:
        log.exception("control connection failed")
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()
