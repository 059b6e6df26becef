"""The bridge in its own process: last will on SIGKILL, its own `offline` on SIGTERM."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import aiomqtt
import pytest
from support.brokers import HOST, Broker, start_broker

REPO = Path(__file__).resolve().parents[2]
PRINTER = "killme"
ONLINE = f"hostd/{PRINTER}/online"

# A small daemon stand-in: a hub that keeps changing, a real controller, the bridge.
CHILD = """
import asyncio, signal, sys
from hostd.api import JobStatus, Snapshot
from hostd.config import MqttConfig
from hostd.publishing.mqtt import MqttBridge
from hostd.publishing.status import StatusHub

class Controller:
    async def handle(self, cmd, args):
        return {}

async def main():
    hub = StatusHub(Snapshot(state="printing"))
    config = MqttConfig(enabled=True, host="127.0.0.1", port=int(sys.argv[1]))
    bridge = MqttBridge(config, sys.argv[2], hub, Controller())
    task = asyncio.current_task()
    asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, task.cancel)
    try:
        async with asyncio.TaskGroup() as group:
            group.create_task(bridge.run(), name="bridge")
            await bridge.connected.wait()
            print("connected", flush=True)
            for layer in range(1_000_000):
                hub.update(job=JobStatus(id="1", name="a.stl", layer=layer, layers=10**6))
                await asyncio.sleep(0.05)
    except asyncio.CancelledError:
        print("stopped", flush=True)

asyncio.run(main())
"""


@pytest.fixture
def broker(tmp_path: Path) -> Broker:
    running = start_broker(tmp_path / "broker")
    yield running
    running.stop()


def start_child(broker: Broker) -> subprocess.Popen[str]:
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(broker.port), PRINTER],
        stdout=subprocess.PIPE, text=True, cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert child.stdout is not None
    assert child.stdout.readline().strip() == "connected"
    return child


async def retained_online(broker: Broker, expected: str) -> None:
    """Wait until the retained availability says ``expected`` (also to a new subscriber)."""
    async with asyncio.timeout(10):
        while True:
            async with aiomqtt.Client(HOST, broker.port) as client:
                await client.subscribe(ONLINE, qos=1)
                async with asyncio.timeout(2):
                    message = await anext(aiter(client.messages))
                assert message.retain
                if message.payload == expected.encode():
                    return
            await asyncio.sleep(0.1)


def test_the_broker_publishes_offline_when_the_daemon_is_killed(broker: Broker) -> None:
    child = start_child(broker)
    try:
        asyncio.run(retained_online(broker, "online"))
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
        asyncio.run(retained_online(broker, "offline"))
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == -signal.SIGKILL
    if broker.kind == "mosquitto":
        assert f"Received DISCONNECT from hostd-{PRINTER}" not in broker.log_file.read_text()


def test_a_clean_stop_publishes_offline_itself(broker: Broker) -> None:
    child = start_child(broker)
    try:
        asyncio.run(retained_online(broker, "online"))
        child.send_signal(signal.SIGTERM)
        out, _ = child.communicate(timeout=10)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0
    assert out.strip() == "stopped"
    # mosquitto sends no last will after a clean DISCONNECT: this `offline` is the bridge's own
    asyncio.run(retained_online(broker, "offline"))
    if broker.kind == "mosquitto":
        assert f"Received DISCONNECT from hostd-{PRINTER}" in broker.log_file.read_text()
