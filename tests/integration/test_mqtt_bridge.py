"""The MQTT bridge against a real broker: availability, status rate, events, commands, reconnect."""

from __future__ import annotations

import asyncio
import itertools
import json
import ssl
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from support.brokers import Broker, make_self_signed, start_broker
from support.doubles import RecordingController
from support.mqtt_helpers import (
    PRINTER,
    SECRET,
    USER,
    Observer,
    observe,
    observer_client,
    settings,
    topic,
    with_bridge,
)
from support.waiting import until

from hostd.api import JobStatus, Snapshot
from hostd.config import MqttConfig
from hostd.publishing.mqtt import Backoff, MqttBridge, MqttSetupError
from hostd.publishing.status import StatusHub

FAST = Backoff(initial_s=0.1, maximum_s=0.5)


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    running = start_broker(tmp_path / "broker")
    yield running
    running.stop()


@pytest.fixture
def secured_broker(tmp_path: Path) -> Any:
    running = start_broker(tmp_path / "broker", users={USER: SECRET})
    yield running
    running.stop()


def test_online_status_events_and_offline_on_clean_exit(broker: Broker) -> None:
    hub = StatusHub(Snapshot(state="idle"))
    bridge = MqttBridge(settings(broker), PRINTER, hub, RecordingController())

    async def body(observer: Observer) -> None:
        async def while_running() -> None:
            await observer.wait_for(lambda: [m for m in observer.on(topic("online"))
                                             if m.payload == "online"])
            await observer.wait_for(lambda: observer.on(topic("status")))
            assert observer.last_json(topic("status")) == hub.current.to_dict()
            hub.event("failed", job="3", name="junk.stl", reason="not an STL file")
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert event["event"] == "failed"
            assert event["reason"] == "not an STL file"

        await with_bridge(bridge, while_running)
        await observer.wait_for(lambda: observer.on(topic("online"))[-1].payload == "offline")

    asyncio.run(observe(broker, body))

    async def late_reader(observer: Observer) -> None:
        # a client arriving later gets the retained availability and the last status
        await observer.wait_for(lambda: observer.on(topic("online")) and observer.on(
            topic("status")))
        online = observer.on(topic("online"))[-1]
        assert online.retain
        assert online.payload == "offline"
        assert observer.on(topic("status"))[-1].retain
        assert observer.last_json(topic("status"))["state"] == "idle"

    asyncio.run(observe(broker, late_reader))


def test_status_is_coalesced_to_one_per_second_but_state_changes_go_at_once(
    broker: Broker,
) -> None:
    hub = StatusHub(Snapshot(state="printing"))
    bridge = MqttBridge(settings(broker), PRINTER, hub, RecordingController())

    async def body(observer: Observer) -> None:
        async def burst() -> None:
            await observer.wait_for(lambda: observer.on(topic("status")))
            start = len(observer.on(topic("status")))
            loop = asyncio.get_running_loop()
            began = loop.time()
            for step in range(250):  # about 2.5 s of updates every 10 ms
                state = "paused" if step == 120 else "printing"
                hub.update(state=state, job=JobStatus(id="1", name="a.stl", layer=step,
                                                      layers=250))
                await asyncio.sleep(0.01)
            duration = loop.time() - began
            final = hub.current.to_dict()
            await observer.wait_for(lambda: observer.last_json(topic("status")) == final, 5)
            published = observer.on(topic("status"))[start:]
            states = [json.loads(item.payload)["state"] for item in published]
            assert "paused" in states, "a state change is published at once"
            assert states.count("paused") == 1
            # 3 state changes (the initial one, to paused and back) may each add one message
            assert len(published) <= int(duration) + 2 + 3, states
            for before, after in itertools.pairwise(published):
                if json.loads(after.payload)["state"] == json.loads(before.payload)["state"]:
                    assert after.at - before.at >= 0.5, "unchanged state: at most 1 Hz"

        await with_bridge(bridge, burst)

    asyncio.run(observe(broker, body))


def test_commands_are_refused_without_allow_commands(secured_broker: Broker) -> None:
    controller = RecordingController()
    bridge = MqttBridge(settings(secured_broker), PRINTER, StatusHub(), controller)

    async def body(observer: Observer) -> None:
        async def send() -> None:
            await observer.client.publish(topic("cmd"), '{"cmd": "pause", "id": 9}', qos=1)
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert event["event"] == "error"
            assert event["cmd"] == "pause"
            assert event["id"] == 9
            assert "allow_commands" in event["reason"]

        await with_bridge(bridge, send)

    asyncio.run(observe(secured_broker, body))
    assert controller.calls == []


def test_commands_are_refused_without_credentials(broker: Broker) -> None:
    controller = RecordingController()
    bridge = MqttBridge(settings(broker, allow_commands=True), PRINTER, StatusHub(), controller)

    async def body(observer: Observer) -> None:
        async def send() -> None:
            await observer.client.publish(topic("cmd"), '{"cmd": "cancel"}', qos=1)
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert event["event"] == "error"
            assert event["cmd"] == "cancel"
            assert "credentials" in event["reason"]

        await with_bridge(bridge, send)

    asyncio.run(observe(broker, body))
    assert controller.calls == []


def test_allowed_commands_reach_the_controller_and_bad_ones_are_answered(
    secured_broker: Broker,
) -> None:
    controller = RecordingController()
    bridge = MqttBridge(
        settings(secured_broker, allow_commands=True), PRINTER, StatusHub(), controller
    )
    bad = [
        ("not json at all", None, "malformed JSON"),
        ('["pause"]', None, "JSON object"),
        ("[" * 60_000, None, "malformed JSON"),
        ('{"cmd": "gcode", "line": "M112"}', "gcode", "unknown command"),
        ('{"cmd": "queue_remove", "job": "1"}', "queue_remove", "unknown command"),
        ('{"cmd": "cancel"}', "cancel", "no job is printing"),
    ]

    async def body(observer: Observer) -> None:
        async def send() -> None:
            await observer.client.publish(topic("cmd"), '{"cmd": "pause"}', qos=1)
            await observer.client.publish(
                topic("cmd"), '{"cmd": "set", "infill.density": 0.4}', qos=1
            )
            for payload, _, _ in bad:
                await observer.client.publish(topic("cmd"), payload, qos=1)
            errors = await observer.wait_for(
                lambda: len(observer.on(topic("event"))) >= len(bad) and observer.on(
                    topic("event"))
            )
            answers = [json.loads(item.payload) for item in errors]
            for answer, (_, cmd, reason) in zip(answers, bad, strict=True):
                assert answer["event"] == "error"
                assert answer["cmd"] == cmd
                assert reason in answer["reason"]

        await with_bridge(bridge, send)

    asyncio.run(observe(secured_broker, body))
    assert controller.calls == [("pause", {}), ("set", {"infill.density": 0.4}), ("cancel", {})]


def test_a_retained_command_is_never_executed(secured_broker: Broker) -> None:
    controller = RecordingController()
    bridge = MqttBridge(
        settings(secured_broker, allow_commands=True), PRINTER, StatusHub(), controller
    )

    async def body(observer: Observer) -> None:
        # left on the broker, it would replay at every reconnect of the daemon
        await observer.client.publish(topic("cmd"), '{"cmd": "cancel"}', qos=1, retain=True)

        async def check() -> None:
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert event["event"] == "error"
            assert "retained" in event["reason"]
            await observer.client.publish(topic("cmd"), b"", qos=1, retain=True)  # clear it

        await with_bridge(bridge, check)

    asyncio.run(observe(secured_broker, body))
    assert controller.calls == []


def test_a_wrong_password_never_connects(secured_broker: Broker) -> None:
    bridge = MqttBridge(
        settings(secured_broker, password="wrong"), PRINTER, StatusHub(), RecordingController(),
        backoff=FAST,
    )

    async def main() -> None:
        task = asyncio.create_task(bridge.run())
        with pytest.raises(TimeoutError):
            async with asyncio.timeout(1.5):
                await bridge.connected.wait()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(main())
    assert "not authorised" in secured_broker.log_file.read_text()


class _RefusingAsCancelled:
    """A client whose connect turns a cancellation into a refusal, as aiomqtt's does on
    Python 3.11 when the broker's "not authorised" and the cancellation come together
    (asyncio.wait_for returns the refusal and the cancellation is lost)."""

    attempts = 0

    async def __aenter__(self) -> None:
        type(self).attempts += 1
        try:
            await asyncio.sleep(0.05)
        except asyncio.CancelledError:
            raise aiomqtt.MqttError("not authorised") from None
        raise aiomqtt.MqttError("not authorised")

    async def __aexit__(self, *exc: object) -> None:
        return None


def test_a_bridge_stopped_while_it_connects_stops_even_if_connecting_loses_the_cancel(
    broker: Broker, monkeypatch
) -> None:
    bridge = MqttBridge(settings(broker), PRINTER, StatusHub(), RecordingController(),
                        backoff=Backoff(initial_s=0.001, maximum_s=0.001))
    monkeypatch.setattr(bridge, "_client", lambda *args, **kwargs: _RefusingAsCancelled())

    async def main() -> None:
        task = asyncio.create_task(bridge.run())
        await until(lambda: _RefusingAsCancelled.attempts >= 2)
        task.cancel()
        async with asyncio.timeout(5):  # it retried for ever: the daemon hung on stop
            with pytest.raises(asyncio.CancelledError):
                await task

    asyncio.run(main())


def test_reconnects_after_a_broker_restart_while_updates_go_on(broker: Broker) -> None:
    hub = StatusHub(Snapshot(state="printing"))
    bridge = MqttBridge(settings(broker, homeassistant=True), PRINTER, hub,
                        RecordingController(), backoff=FAST)
    layers: list[int] = []

    async def printing() -> None:
        for layer in range(10_000):
            hub.update(job=JobStatus(id="1", name="a.stl", layer=layer, layers=10_000))
            layers.append(layer)
            await asyncio.sleep(0.02)

    async def main() -> None:
        producer = asyncio.create_task(printing(), name="printing")

        async def restart() -> None:
            loop = asyncio.get_running_loop()
            broker.stop()
            # counted from the moment the broker goes: a restart can take less than one
            # update's interval, so counting from the restart alone proved nothing
            before = len(layers)
            await asyncio.sleep(0.05)
            await _lost(bridge)
            hub.event("failed", job="2", name="junk.stl", reason="empty file")
            await loop.run_in_executor(None, broker.start)
            async with asyncio.timeout(10):
                await bridge.connected.wait()
            assert len(layers) > before, "the hub kept updating while the broker was away"
            reached = layers[-1]

            async def check(observer: Observer) -> None:
                await observer.wait_for(
                    lambda: observer.on(topic("online"))
                    and observer.on(topic("online"))[-1].payload == "online"
                )
                await observer.wait_for(
                    lambda: (observer.last_json(topic("status")) or {}).get("job", {}).get(
                        "layer", -1) >= reached
                )
                # the restarted broker kept nothing: discovery is announced again
                await observer.wait_for(
                    lambda: [m for m in observer.messages if m.topic.startswith("homeassistant/")]
                )

            await observe(broker, check)

        await with_bridge(bridge, restart)
        producer.cancel()

    asyncio.run(main())


async def _lost(bridge: MqttBridge) -> bool:
    """Wait until the bridge notices the broker is gone."""
    await until(lambda: not bridge.connected.is_set(), 5, "the bridge to see the broker gone")
    return True


def test_events_raised_while_the_broker_is_away_are_published_after_reconnect(
    broker: Broker,
) -> None:
    hub = StatusHub()
    # reconnecting 1-2 s after the loss leaves time for the listener to subscribe first
    slow = Backoff(initial_s=2.0, maximum_s=2.0)
    bridge = MqttBridge(settings(broker), PRINTER, hub, RecordingController(), backoff=slow)

    async def main() -> None:
        received: list[dict[str, Any]] = []
        arrived = asyncio.Event()

        async def listen() -> None:
            while True:
                try:
                    async with observer_client(broker) as client:
                        await client.subscribe(topic("event"), qos=1)
                        async for message in client.messages:
                            received.append(json.loads(message.payload))
                            arrived.set()
                except aiomqtt.MqttError:
                    await asyncio.sleep(0.1)

        async def outage() -> None:
            broker.stop()
            await _lost(bridge)
            hub.event("failed", job="2", name="junk.stl", reason="empty file")
            await asyncio.get_running_loop().run_in_executor(None, broker.start)
            listener = asyncio.create_task(listen())
            async with asyncio.timeout(10):
                while not any(item.get("event") == "failed" for item in received):
                    arrived.clear()
                    await arrived.wait()
            listener.cancel()

        await with_bridge(bridge, outage)

    asyncio.run(main())


def test_tls_with_a_self_signed_certificate(tmp_path: Path) -> None:
    files = make_self_signed(tmp_path)
    running = start_broker(tmp_path / "broker", users={USER: SECRET}, tls=files)
    try:
        hub = StatusHub(Snapshot(state="heating"))
        trusting = MqttBridge(
            settings(running, tls=True, ca_file=str(files.cert)), PRINTER, hub,
            RecordingController(),
        )
        context = ssl.create_default_context(cafile=str(files.cert))

        async def body(observer: Observer) -> None:
            async def check() -> None:
                status = await observer.wait_for(lambda: observer.last_json(topic("status")))
                assert status["state"] == "heating"

            await with_bridge(trusting, check)

        asyncio.run(observe(running, body, tls=context))

        # without the CA the broker's certificate is not trusted: no connection
        untrusting = MqttBridge(
            settings(running, tls=True), PRINTER, hub, RecordingController(), backoff=FAST
        )

        async def refused() -> None:
            task = asyncio.create_task(untrusting.run())
            with pytest.raises(TimeoutError):
                async with asyncio.timeout(1.0):
                    await untrusting.connected.wait()
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

        asyncio.run(refused())
    finally:
        running.stop()


def test_a_missing_ca_file_is_refused_at_start(tmp_path: Path) -> None:
    config = MqttConfig(enabled=True, tls=True, ca_file=str(tmp_path / "missing.pem"))
    with pytest.raises(MqttSetupError, match="ca_file"):
        MqttBridge(config, PRINTER, StatusHub(), RecordingController())
    with pytest.raises(MqttSetupError, match="topic"):
        MqttBridge(MqttConfig(enabled=True), "a/b", StatusHub(), RecordingController())
