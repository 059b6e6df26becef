"""The control socket server against real Unix sockets: mode, status, subscribe, commands."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import stat
import sys
import threading
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.doubles import RecordingController
from support.waiting import until

from hostd.api import ControlClient, ControlError, JobStatus, Snapshot
from hostd.publishing.control import ControlSocketError, serve_control
from hostd.publishing.status import StatusHub

REPO = Path(__file__).resolve().parents[2]


Scenario = Callable[[Path, StatusHub, RecordingController], Awaitable[None]]


def serve(tmp_path: Path, scenario: Scenario, path: Path | None = None) -> RecordingController:
    """Run ``scenario`` against a live serve_control; check the socket is gone afterwards."""
    path = path or tmp_path / "hostd.sock"
    hub = StatusHub(Snapshot(state="idle"))
    controller = RecordingController()

    async def main() -> None:
        server = asyncio.create_task(serve_control(path, hub, controller), name="control")
        await asyncio.sleep(0)  # binds and listens synchronously in its first step
        try:
            await asyncio.wait_for(scenario(path, hub, controller), 20)
        finally:
            server.cancel()
            with pytest.raises(asyncio.CancelledError):
                await server
        assert not path.exists(), "the socket file must be removed on exit"

    asyncio.run(main())
    return controller


async def raw_exchange(path: Path, lines: list[bytes]) -> list[dict[str, Any]]:
    """Send raw request lines on one connection and read one reply per line."""
    reader, writer = await asyncio.open_unix_connection(str(path))
    replies = []
    try:
        for line in lines:
            writer.write(line)
            await writer.drain()
            replies.append(json.loads(await reader.readline()))
    finally:
        writer.close()
        await writer.wait_closed()
    return replies


def test_socket_is_private_and_answers_status(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, _: RecordingController) -> None:
        assert stat.S_ISSOCK(path.lstat().st_mode)
        assert stat.S_IMODE(path.lstat().st_mode) == 0o600
        hub.update(state="printing", job=JobStatus(id="7", name="part.stl", layer=3, layers=9))
        async with ControlClient(str(path)) as client:
            snapshot = await client.status()
            raw = await client.request("status", id=41)
        assert snapshot.state == "printing"
        assert snapshot.job is not None
        assert snapshot.job.layer == 3
        assert raw["reply"] == "status"
        assert raw["ok"] is True
        assert raw["id"] == 41
        assert raw["status"] == hub.current.to_dict()

    serve(tmp_path, scenario)


def test_subscribe_streams_status_and_events_to_many_clients(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, _: RecordingController) -> None:
        clients = [ControlClient(str(path)) for _ in range(5)]
        streams = []
        for client in clients:
            await client.__aenter__()
            stream = client.subscribe()
            first = await anext(stream)
            assert first["status"].state == "idle"  # the current snapshot comes first
            streams.append(stream)
        hub.update(state="heating")
        hub.event("started", job="7", name="part.stl")
        for stream in streams:
            assert (await anext(stream))["status"].state == "heating"
            event = (await anext(stream))["event"]
            assert event["event"] == "started"
            assert event["name"] == "part.stl"
        for client in clients:
            await client.__aexit__(None, None, None)

    serve(tmp_path, scenario)


def test_commands_reach_the_controller_and_refusals_are_answered(tmp_path: Path) -> None:
    async def scenario(path: Path, _: StatusHub, controller: RecordingController) -> None:
        replies = await raw_exchange(
            path,
            [
                b'{"cmd": "pause", "id": 1}\n',
                b'{"cmd": "cancel_object", "object": 2}\n',
                b"this is not json\n",
                b"[1, 2]\n",
                b'{"no_cmd": true}\n',
                b'{"cmd": "gcode", "line": "M112"}\n',
                b'{"cmd": "cancel", "id": "c"}\n',
                b'{"cmd": "set", "boom": 1}\n',
                b"[" * 100_000 + b"\n",
                b'{"cmd": "resume"}\n',
            ],
        )
        pause, cancel_object, garbage, array, no_cmd, gcode, cancel, bug, deep, resume = replies
        assert deep["ok"] is False
        assert "malformed JSON" in deep["error"]
        assert pause == {"reply": "pause", "ok": True, "id": 1, "error": None, "done": "pause"}
        assert cancel_object["ok"] is True
        assert garbage["ok"] is False
        assert "malformed JSON" in garbage["error"]
        assert array["ok"] is False
        assert "JSON object" in array["error"]
        assert no_cmd["ok"] is False
        assert "cmd" in no_cmd["error"]
        assert gcode["ok"] is False
        assert "unknown command 'gcode'" in gcode["error"]
        assert cancel == {"reply": "cancel", "ok": False, "id": "c", "error": "no job is printing"}
        assert bug["ok"] is False
        assert "ZeroDivisionError" in bug["error"]
        assert resume["ok"] is True  # the connection survived every bad line
        with pytest.raises(ControlError, match="no job is printing"):
            async with ControlClient(str(path)) as client:
                await client.request("cancel")

    controller = serve(tmp_path, scenario)
    assert [cmd for cmd, _ in controller.calls] == [
        "pause", "cancel_object", "cancel", "set", "resume", "cancel"
    ]
    assert controller.calls[1] == ("cancel_object", {"object": 2})


def test_requests_on_a_subscribed_connection_are_still_answered(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, controller: RecordingController) -> None:
        reader, writer = await asyncio.open_unix_connection(str(path))
        writer.write(b'{"cmd": "subscribe"}\n')
        assert json.loads(await reader.readline())["reply"] == "subscribe"
        assert "status" in json.loads(await reader.readline())
        writer.write(b'{"cmd": "pause"}\n')
        assert json.loads(await reader.readline())["reply"] == "pause"
        hub.update(state="paused")
        assert json.loads(await reader.readline())["status"]["state"] == "paused"
        writer.close()
        await writer.wait_closed()
        assert controller.calls == [("pause", {})]

    serve(tmp_path, scenario)


def test_an_overlong_line_is_refused_and_the_server_lives_on(tmp_path: Path) -> None:
    async def scenario(path: Path, _: StatusHub, __: RecordingController) -> None:
        reader, writer = await asyncio.open_unix_connection(str(path))
        writer.write(b"x" * (2 << 20) + b"\n")
        reply = json.loads(await reader.readline())
        assert reply["ok"] is False
        assert "too long" in reply["error"]
        writer.close()
        async with ControlClient(str(path)) as client:
            assert (await client.status()).state == "idle"

    serve(tmp_path, scenario)


def test_a_client_that_vanishes_mid_stream_does_not_hurt_the_others(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, _: RecordingController) -> None:
        _, rude = await asyncio.open_unix_connection(str(path))
        rude.write(b'{"cmd": "subscribe"}\n')
        await rude.drain()
        rude.transport.abort()
        for layer in range(50):
            hub.event("layer", layer=layer)
            hub.update(state="printing")
            await asyncio.sleep(0)
        async with ControlClient(str(path)) as client:
            assert (await client.status()).state == "printing"

    serve(tmp_path, scenario)


def test_a_stale_socket_is_replaced(tmp_path: Path) -> None:
    path = tmp_path / "hostd.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as dead:
        dead.bind(str(path))  # bound, never listening, then closed: what a kill -9 leaves
    assert path.exists()

    async def scenario(path: Path, _: StatusHub, __: RecordingController) -> None:
        async with ControlClient(str(path)) as client:
            assert (await client.status()).state == "idle"

    serve(tmp_path, scenario, path)


def test_a_live_socket_or_another_file_is_never_taken_over(tmp_path: Path) -> None:
    path = tmp_path / "hostd.sock"
    hub = StatusHub()

    async def main() -> None:
        first = asyncio.create_task(serve_control(path, hub, RecordingController()))
        await asyncio.sleep(0)
        with pytest.raises(ControlSocketError, match="another daemon"):
            await serve_control(path, hub, RecordingController())
        first.cancel()
        with pytest.raises(asyncio.CancelledError):
            await first

    asyncio.run(main())
    path.write_text("not a socket")
    with pytest.raises(ControlSocketError, match="not a socket"):
        asyncio.run(serve_control(path, hub, RecordingController()))
    assert path.read_text() == "not a socket"


def test_the_socket_file_appears_only_once_it_listens(tmp_path: Path, monkeypatch) -> None:
    # bound at its own path, a client that saw the file between bind() and listen() was
    # refused; it is now bound aside and linked into place once listening
    from hostd.publishing import control

    path = tmp_path / "hostd.sock"
    seen: list[bool] = []

    class Watched(socket.socket):
        def listen(self, *args: Any) -> None:
            seen.append(path.exists())
            super().listen(*args)

    monkeypatch.setattr(control.socket, "socket", Watched)
    sock = control._bind_private(path)
    monkeypatch.undo()
    try:
        assert seen == [False]
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        assert [p.name for p in tmp_path.iterdir()] == ["hostd.sock"]  # nothing left aside
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
            client.connect(str(path))
    finally:
        sock.close()


def test_a_socket_another_daemon_bound_meanwhile_is_not_replaced(tmp_path: Path,
                                                                 monkeypatch) -> None:
    from hostd.publishing import control

    path = tmp_path / "hostd.sock"
    other = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)

    class Raced(socket.socket):
        def listen(self, *args: Any) -> None:
            other.bind(str(path))  # another daemon, between this one's claim and its link
            other.listen(1)
            super().listen(*args)

    monkeypatch.setattr(control.socket, "socket", Raced)
    try:
        with pytest.raises(ControlSocketError, match="another daemon"):
            control._bind_private(path)
        monkeypatch.undo()
        assert [p.name for p in tmp_path.iterdir()] == ["hostd.sock"]
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
            client.connect(str(path))  # the other daemon's, still serving
    finally:
        other.close()


def run_cli(*args: str) -> Callable[[], Awaitable[tuple[int, str, str]]]:
    async def call() -> tuple[int, str, str]:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())",
            *args,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, cwd=REPO,
            env={**os.environ, "PYTHONPATH": str(REPO)},
        )
        out, err = await proc.communicate()
        assert proc.returncode is not None
        return proc.returncode, out.decode(), err.decode()

    return call


def test_hostd_status_reads_the_running_daemon(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, _: RecordingController) -> None:
        hub.update(
            state="printing",
            job=JobStatus(id="12", name="bunny.stl", layer=40, layers=120, progress=0.33,
                          eta_s=3725.0),
            queue=("cube.stl",),
        )
        code, out, err = await run_cli("status", "--json", "--socket", str(path))()
        assert code == 0, err
        assert json.loads(out) == hub.current.to_dict()
        code, out, err = await run_cli("status", "--socket", str(path))()
        assert code == 0, err
        assert "printing" in out
        assert "bunny.stl" in out
        assert "layer 41 of 120" in out
        assert "1:02:05" in out
        assert "cube.stl" in out

    serve(tmp_path, scenario)


def test_hostd_status_finds_the_socket_through_the_config(tmp_path: Path) -> None:
    config = tmp_path / "hostd.toml"
    config.write_text(f'[state]\nfolder = "{tmp_path / "state"}"\n')

    async def scenario(path: Path, _: StatusHub, __: RecordingController) -> None:
        code, out, err = await run_cli("status", "--json", "--config", str(config))()
        assert code == 0, err
        assert json.loads(out)["state"] == "idle"

    from hostd.app.commands.target import SOCKET_NAME

    serve(tmp_path, scenario, tmp_path / "state" / SOCKET_NAME)


def test_hostd_status_without_a_daemon_fails_with_a_reason(tmp_path: Path) -> None:
    code, out, err = asyncio.run(run_cli("status", "--socket", str(tmp_path / "none.sock"))())
    assert code == 1
    assert out == ""
    assert "cannot reach the daemon" in err
    bad = tmp_path / "bad.toml"
    bad.write_text("[state]\nfolder = 3\n")
    code, _, err = asyncio.run(run_cli("status", "--config", str(bad))())
    assert code == 2
    assert "state.folder" in err


def test_many_clients_at_once_all_follow_the_hub(tmp_path: Path) -> None:
    async def scenario(path: Path, hub: StatusHub, _: RecordingController) -> None:
        following: set[int] = set()  # clients that have their first snapshot: subscribed

        async def client(number: int) -> str:
            async with ControlClient(str(path)) as control:
                await control.request("pause", id=number)
                async for item in control.subscribe():
                    following.add(number)
                    status = item.get("status")
                    if status is not None and status.job is not None and status.job.layer == 99:
                        return status.state
            return "closed"

        clients = [asyncio.create_task(client(n)) for n in range(40)]
        await until(lambda: len(following) == 40, 10, "every client subscribed")
        for layer in range(100):
            hub.update(state="printing", job=JobStatus(id="1", name="a.stl", layer=layer))
            await asyncio.sleep(0.001)
        assert await asyncio.gather(*clients) == ["printing"] * 40

    controller = serve(tmp_path, scenario)
    assert controller.calls == [("pause", {})] * 40


@pytest.fixture(scope="module")
def server_in_thread(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One control socket served from its own thread and event loop for the whole module."""
    path = tmp_path_factory.mktemp("threaded") / "hostd.sock"
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    serving: list[asyncio.Task[None]] = []

    async def main() -> None:
        serving.append(asyncio.create_task(serve_control(path, StatusHub(),
                                                         RecordingController())))
        await asyncio.sleep(0)
        ready.set()
        with contextlib.suppress(asyncio.CancelledError):
            await serving[0]

    thread = threading.Thread(target=lambda: loop.run_until_complete(main()), daemon=True)
    thread.start()
    assert ready.wait(10)
    yield path
    loop.call_soon_threadsafe(serving[0].cancel)
    thread.join(10)
    loop.close()
    assert not path.exists()


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(line=st.binary(max_size=300).filter(lambda b: b"\n" not in b and b.strip()))
def test_any_request_line_gets_a_reply_and_the_connection_survives(
    server_in_thread: Path, line: bytes
) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(10)
        sock.connect(str(server_in_thread))
        stream = sock.makefile("rwb")
        stream.write(line + b'\n{"cmd": "status"}\n')
        stream.flush()
        reply = json.loads(stream.readline())
        assert set(reply) >= {"reply", "ok", "id", "error"}
        assert reply["ok"] is False or reply["reply"] in ("status", "subscribe", "pause",
                                                           "resume", "resume_job", "set",
                                                           "cancel_object", "queue_move",
                                                           "queue_remove")
        if reply["reply"] == "subscribe" and reply["ok"]:
            assert "status" in json.loads(stream.readline())  # the stream's first snapshot
        follow = json.loads(stream.readline())
        assert follow["reply"] == "status"
        assert follow["ok"] is True
