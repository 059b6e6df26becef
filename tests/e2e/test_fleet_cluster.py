"""`mqtt.hosts` failover: between two mosquittos, and across a three-node nats-server cluster."""

from __future__ import annotations

import asyncio
import json
import signal
import time
from pathlib import Path
from typing import Any

import aiomqtt
from support.brokers import HOST, start_broker, start_nats_cluster
from support.daemon_process import sim_config
from support.doubles import RecordingController
from support.fleet_helpers import rows
from support.paths import DATA
from support.waiting import until

from hostd.api import Snapshot
from hostd.config import MqttConfig
from hostd.jobs.jobstore import JobStore
from hostd.publishing.mqtt import Backoff, MqttBridge
from hostd.publishing.status import StatusHub
from tui.fleet import FleetApp, FleetScreen
from tui.sources import MqttSource


def test_the_bridge_fails_over_to_the_next_broker_of_mqtt_hosts(tmp_path: Path) -> None:
    first, second = start_broker(tmp_path / "a"), start_broker(tmp_path / "b")
    config = MqttConfig(enabled=True, hosts=((HOST, first.port), (HOST, second.port)))
    hub = StatusHub(Snapshot(state="idle"))
    controller = RecordingController(refuse_all="not in this test")
    bridge = MqttBridge(config, "fo1", hub, controller, status_interval_s=0.1,
                        backoff=Backoff(initial_s=0.1, maximum_s=1.0))

    async def scenario() -> None:
        task = asyncio.create_task(bridge.run())
        async with asyncio.timeout(20):
            await bridge.connected.wait()
        assert bridge.broker == (HOST, first.port)
        async with aiomqtt.Client(HOST, second.port) as watcher:
            await watcher.subscribe("hostd/fo1/status", qos=1)
            first.stop()
            hub.update(state="printing")
            async with asyncio.timeout(20):
                async for message in watcher.messages:
                    status = Snapshot.from_dict(json.loads(message.payload))
                    if status.state == "printing" and message.qos == 1:  # the session's own
                        break  # (the standby link's copies come at QoS 0, not retained)
        assert bridge.broker == (HOST, second.port)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    try:
        asyncio.run(scenario())
    finally:
        first.stop()
        second.stop()
    assert controller.calls == []  # failing over sends the printer no command


def test_the_standby_link_carries_the_status_while_the_session_is_away(tmp_path: Path) -> None:
    first, second = start_broker(tmp_path / "a"), start_broker(tmp_path / "b")
    config = MqttConfig(enabled=True, hosts=((HOST, first.port), (HOST, second.port)))
    hub = StatusHub(Snapshot(state="printing"))
    # after the drop the session waits 15 to 30 s before it tries the second broker:
    # meanwhile only the standby link can bring the status there
    bridge = MqttBridge(config, "sb1", hub, RecordingController(refuse_all="not in this test"),
                        status_interval_s=0.2,
                        backoff=Backoff(initial_s=30.0, maximum_s=30.0))
    assert bridge.standby is not None
    alone = MqttConfig(enabled=True, host=HOST, port=first.port)
    assert MqttBridge(alone, "sb2", hub, RecordingController()).standby is None  # one broker

    async def scenario() -> None:
        task = asyncio.create_task(bridge.run())
        async with asyncio.timeout(20):
            await bridge.connected.wait()
        await until(lambda: bridge.standby.broker is not None, timeout=20,
                    what="the standby link connected")
        assert bridge.broker == (HOST, first.port)
        assert bridge.standby.broker == (HOST, second.port)
        assert bridge.standby.published == 0  # quiet while the session is up
        async with aiomqtt.Client(HOST, second.port) as watcher:
            await watcher.subscribe("hostd/sb1/status", qos=1)
            first.stop()
            await until(lambda: not bridge.connected.is_set(), timeout=10,
                        what="the session to notice its broker gone")
            carried = []
            for n in range(2):  # the newest status, once an interval
                made = hub.update(state="printing", error=f"status {n}").ts
                async with asyncio.timeout(10):
                    async for message in watcher.messages:
                        status = Snapshot.from_dict(json.loads(message.payload))
                        if status.ts >= made:
                            carried.append((message.qos, message.retain, status.error))
                            break
        assert carried == [(0, False, "status 0"), (0, False, "status 1")]
        assert not bridge.connected.is_set()  # the session itself was not back yet
        assert bridge.standby.published >= 2
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    try:
        asyncio.run(scenario())
    finally:
        first.stop()
        second.stop()


def test_a_print_goes_on_when_its_nats_node_stops_and_the_fleet_sees_it_through_another(
    tmp_path: Path, daemon: Any
) -> None:
    cluster = start_nats_cluster(tmp_path / "nats")
    try:
        hosts = ", ".join(f'"{host}"' for host in cluster.hosts())
        hostd = daemon(sim_config(time_scale=0.01, extra=(
            f'[printer]\nid = "cl1"\n[mqtt]\nenabled = true\nhosts = [{hosts}]\n')))
        hostd.drop(DATA / "cube20_xyz.stl", "cube.stl")
        back_after: list[float] = []

        async def scenario() -> None:
            watcher = cluster.nodes[2]  # the fleet view stays on the third node
            app = FleetApp(MqttSource([(HOST, watcher.mqtt_port)]), refresh_s=0.05)
            async with app.run_test(size=(100, 30)):
                await until(lambda: dict(rows(app)).get("cl1") == "printing", timeout=90)
                assert f"MQTT connected to {cluster.hosts()[0]}" in hostd.run_log()
                screen = app.screen
                assert isinstance(screen, FleetScreen)

                def newest_ts() -> float:
                    snap = screen.model.entries["cl1"].snapshot
                    return snap.ts if snap is not None else 0.0

                node = cluster.nodes[0]  # the daemon's node stops mid-print
                assert node.process is not None
                stopped = time.time()
                node.process.send_signal(signal.SIGTERM)
                await until(lambda: newest_ts() > stopped + 0.5
                            and dict(rows(app)).get("cl1") == "printing", timeout=30.0)
                back_after.append(time.time() - stopped)
                await asyncio.to_thread(node.stop)

        asyncio.run(scenario())
        assert back_after  # how soon is a figure for bench/, not a test's assertion
        # the next broker in turn; the one after it if that one refused (a loaded machine)
        after_stop = hostd.run_log().split(f"MQTT connected to {cluster.hosts()[0]}", 1)[1]
        assert any(f"MQTT connected to {host}" in after_stop for host in cluster.hosts()[1:])
        done = hostd.jobs / "done" / "cube.summary.txt"
        hostd.wait_for(done.exists, 180, "the job done")
        store = JobStore(hostd.state / "jobs.sqlite3")
        states = [entry.to_state for entry in store.history("1")]
        store.close()
        assert states == ["queued", "slicing", "heating", "printing", "done"]  # undisturbed
    finally:
        cluster.stop()


def test_mqtt_hosts_are_read_and_checked(tmp_path: Path) -> None:
    import pytest

    from hostd.config import ConfigError, config_from_mapping

    config = config_from_mapping({"mqtt": {"port": 1884, "hosts": ["a:1", "b", "c.farm:65535"]}},
                                 tmp_path)
    assert config.mqtt.brokers == (("a", 1), ("b", 1884), ("c.farm", 65535))
    assert config_from_mapping({"mqtt": {"host": "x", "port": 2}}, tmp_path).mqtt.brokers == (
        ("x", 2),)
    for bad, reason in [("a:1", "a list"), (["a:0"], "1..65535"), (["a:b"], "1..65535"),
                        (["a b"], "not host"), ([":5"], "not host"), ([3], "a list")]:
        with pytest.raises(ConfigError, match=reason) as caught:
            config_from_mapping({"mqtt": {"hosts": bad}}, tmp_path)
        assert caught.value.key == "mqtt.hosts"
