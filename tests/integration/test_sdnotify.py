"""The systemd notify protocol against a real AF_UNIX datagram socket, as systemd listens."""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from hostd.api import JobStatus, PrinterInfo, Snapshot
from hostd.app.sdnotify import notify, status_line, watchdog, watchdog_interval
from hostd.publishing.status import StatusHub


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = tmp_path / "notify"
    sock.bind(str(path))
    sock.settimeout(5)
    yield sock, str(path)
    sock.close()


def receive(sock: socket.socket) -> list[str]:
    return sock.recv(4096).decode().split("\n")


def test_ready_and_status_arrive_in_one_datagram(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    assert notify("READY=1", "STATUS=idle", env={"NOTIFY_SOCKET": path})
    assert receive(sock) == ["READY=1", "STATUS=idle"]
    assert notify("STOPPING=1", env={"NOTIFY_SOCKET": path})
    assert receive(sock) == ["STOPPING=1"]


def test_the_environment_is_read_by_default(
    listener: tuple[socket.socket, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    sock, path = listener
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    assert notify("WATCHDOG=1")
    assert receive(sock) == ["WATCHDOG=1"]


def test_abstract_socket_names() -> None:
    name = f"hostd-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(5)
        assert notify("READY=1", env={"NOTIFY_SOCKET": "@" + name})
        assert receive(sock) == ["READY=1"]


def test_without_a_service_manager_nothing_is_sent(tmp_path: Path) -> None:
    assert notify("READY=1", env={}) is False
    assert notify("READY=1", env={"NOTIFY_SOCKET": "vsock:2:999"}) is False
    # a socket path nobody listens on: the manager is gone, which is not an error
    assert notify("READY=1", env={"NOTIFY_SOCKET": str(tmp_path / "gone")}) is False


def test_watchdog_interval() -> None:
    assert watchdog_interval({}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "30000000"}) == 30.0
    assert watchdog_interval({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "soon"}) is None
    mine = str(os.getpid())
    assert watchdog_interval({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": mine}) == 2.0
    other = str(os.getpid() + 1)
    assert watchdog_interval({"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": other}) is None


def test_watchdog_pings_and_reports_status_changes(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    sock.setblocking(False)
    env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"}  # pings every 0.1 s
    hub = StatusHub(Snapshot(state="idle", printer=PrinterInfo(connected=True)))

    async def main() -> list[str]:
        loop = asyncio.get_running_loop()
        task = asyncio.create_task(watchdog(hub, env))
        got: list[str] = []

        async def until(wanted: str, count: int = 1) -> None:
            async with asyncio.timeout(5):
                while got.count(wanted) < count:
                    got.extend((await loop.sock_recv(sock, 4096)).decode().split("\n"))

        await until("STATUS=idle")
        await until("WATCHDOG=1")
        hub.update(state="printing", job=JobStatus(id="1", name="a.stl", layer=2, layers=10,
                                                   progress=0.2))
        await until("STATUS=printing a.stl layer 3 of 10 (20%)")
        pings = got.count("WATCHDOG=1")
        hub.update()  # same summary: no new STATUS
        got.clear()
        await until("WATCHDOG=1", count=2)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert pings >= 1
        return got

    later = asyncio.run(main())
    assert not [line for line in later if line.startswith("STATUS=")]


def test_watchdog_returns_at_once_outside_systemd() -> None:
    asyncio.run(asyncio.wait_for(watchdog(StatusHub(), env={}), 5))


def test_status_line_is_one_readable_line() -> None:
    snapshot = Snapshot(
        state="printing",
        printer=PrinterInfo(connected=True),
        job=JobStatus(id="1", name="my part.stl", layer=5, layers=50, progress=0.1, eta_s=3700),
        queue=("b.stl", "c.stl"),
    )
    assert status_line(snapshot) == (
        "printing my part.stl layer 6 of 50 (10%), ETA 1:01:40, 2 queued"
    )
    assert status_line(Snapshot(state="error", error="thermal\nrunaway")) == (
        "error: thermal runaway, printer not connected"
    )
