"""`hostd run` with MQTT on a real broker: a bad model's `failed` event, commands, availability."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from support.brokers import HOST, Broker, start_broker

REPO = Path(__file__).resolve().parents[2]
HOSTD = ["-c", "import sys; from hostd.app.cli import main; sys.exit(main())"]
PRINTER = "farm7"
USER, SECRET = "daemon", "pw-7"


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    running = start_broker(tmp_path / "broker", users={USER: SECRET})
    yield running
    running.stop()


def start_daemon(folder: Path, broker: Broker) -> subprocess.Popen[str]:
    config = folder / "hostd.toml"
    config.write_text(
        "[jobs]\nfolder = \"jobs\"\nsettle_s = 0.2\n"
        "[state]\nfolder = \"var\"\n"
        f"[printer]\nid = \"{PRINTER}\"\n"
        "[simulator]\ntime_scale = 0\nbaud = 0\n"
        f"[mqtt]\nenabled = true\nhost = \"{HOST}\"\nport = {broker.port}\n"
        f"username = \"{USER}\"\npassword = \"{SECRET}\"\nallow_commands = true\n"
    )
    return subprocess.Popen(
        [sys.executable, *HOSTD, "run", "--config", str(config)],
        cwd=folder, env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )


def test_a_bad_model_fails_with_an_mqtt_event_and_commands_are_answered_emergency_stop_too(
    tmp_path: Path, broker: Broker
) -> None:
    daemon = start_daemon(tmp_path, broker)

    async def watch() -> tuple[dict[str, Any], dict[str, Any], str]:
        failed: dict[str, Any] | None = None
        refused: dict[str, Any] | None = None
        sent = False
        async with aiomqtt.Client(HOST, broker.port, username=USER, password=SECRET) as client:
            await client.subscribe(f"hostd/{PRINTER}/#", qos=1)
            async with asyncio.timeout(40):
                async for message in client.messages:
                    topic = str(message.topic)
                    if not sent and topic.endswith("/status") and json.loads(
                            message.payload).get("printer", {}).get("connected"):
                        # the daemon is up with its printer connected: drop a model that
                        # cannot be printed, send commands (carried out in order: the
                        # pause's refusal follows the stop)
                        sent = True
                        (tmp_path / "jobs" / "junk.stl").write_bytes(b"\x00" * 40)
                        await client.publish(f"hostd/{PRINTER}/cmd", '{"cmd": "emergency_stop"}',
                                             qos=1)
                        await client.publish(f"hostd/{PRINTER}/cmd", '{"cmd": "pause"}', qos=1)
                    elif topic.endswith("/event"):
                        event = json.loads(message.payload)
                        if event["event"] == "failed":
                            failed = event
                        elif event["event"] == "error" and event.get("cmd") == "pause":
                            refused = event
                    if failed and refused:
                        break
            daemon.send_signal(signal.SIGTERM)
            async with asyncio.timeout(30):
                async for message in client.messages:
                    if str(message.topic).endswith("/online"):
                        return failed, refused, message.payload.decode()
        raise AssertionError("unreachable")

    try:
        failed, refused, availability = asyncio.run(watch())
        output, _ = daemon.communicate(timeout=30)
    except BaseException:
        if daemon.poll() is None:
            daemon.kill()
        sys.stderr.write(daemon.communicate()[0])  # the daemon's log, shown with the failure
        raise
    assert "junk" in json.dumps(failed)
    assert (tmp_path / "jobs" / "failed" / "junk.error.txt").exists()
    assert refused["reason"] == "no job is printing"  # the daemon's controller answered
    # the emergency stop reached the printer: M112 halted it, and the link was opened again
    assert "emergency stop requested" in output
    assert "M112" in (tmp_path / "var" / "simulator-executed.log").read_text()
    assert availability == "offline", output
    assert daemon.returncode == 0, output


BAD_INPUTS = {
    "empty.stl": b"",
    "noise.stl": bytes(range(256)) * 7,
    "words.stl": b"solid x\nthis is not a facet\nendsolid x\n",
    "short.stl": b"\x00" * 80 + (1000).to_bytes(4, "little") + b"\x01" * 50,
}


def test_bad_models_fail_on_mqtt_and_the_next_job_prints_with_pause_and_resume(
    tmp_path: Path, broker: Broker
) -> None:
    daemon = start_daemon(tmp_path, broker)
    cube = (REPO / "tests" / "data" / "cube20_xyz.stl").read_bytes()

    async def watch() -> tuple[dict[str, dict[str, Any]], list[str], list[str]]:
        failed: dict[str, dict[str, Any]] = {}
        events: list[str] = []
        states: list[str] = []
        cmd = f"hostd/{PRINTER}/cmd"
        async with aiomqtt.Client(HOST, broker.port, username=USER, password=SECRET) as client:
            await client.subscribe(f"hostd/{PRINTER}/#", qos=1)
            async with asyncio.timeout(60):
                async for message in client.messages:
                    topic = str(message.topic)
                    if topic.endswith("/online") and message.payload == b"online":
                        for name, data in BAD_INPUTS.items():
                            (tmp_path / "jobs" / name).write_bytes(data)
                    elif topic.endswith("/status"):
                        states.append(json.loads(message.payload)["state"])
                    elif topic.endswith("/event"):
                        event = json.loads(message.payload)
                        kind = event["event"]
                        events.append(kind)
                        if kind == "failed":
                            failed[event["name"]] = event
                            if len(failed) == len(BAD_INPUTS):
                                (tmp_path / "jobs" / "cube.stl").write_bytes(cube)
                        elif kind == "layer" and "pause" not in events:
                            events.append("pause")
                            await client.publish(cmd, '{"cmd": "pause"}', qos=1)
                        elif kind == "paused":
                            await client.publish(cmd, '{"cmd": "resume"}', qos=1)
                        elif kind == "error":
                            raise AssertionError(f"command refused: {event}")
                        elif kind == "done":
                            break
        return failed, events, states

    try:
        failed, events, states = asyncio.run(watch())
    finally:
        daemon.send_signal(signal.SIGTERM)
        try:
            daemon.communicate(timeout=30)
        finally:
            if daemon.poll() is None:
                daemon.kill()
                daemon.wait()
    assert set(failed) == set(BAD_INPUTS)
    reasons = {event["reason"] for event in failed.values()}
    assert len(reasons) >= 3, f"each bad input has its own reason: {reasons}"
    for name in BAD_INPUTS:
        assert (tmp_path / "jobs" / "failed" / name).exists()
    kinds = [kind for kind in events if kind in ("started", "paused", "resumed", "done")]
    assert kinds == ["started", "paused", "resumed", "done"], events
    # state changes go out at once
    assert "printing" in states, states
    assert "paused" in states, states
    assert (tmp_path / "jobs" / "done" / "cube.gcode").exists()
