"""Read-only requests over MQTT against a real broker: replies, reply topics, sizes, a flood."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest
from support.brokers import Broker, start_broker, start_nats_cluster
from support.doubles import RecordingController
from support.mqtt_helpers import PRINTER, Observer, observe, settings, topic, with_bridge
from support.waiting import until

from hostd.api import ControlError, Snapshot
from hostd.config import MqttConfig
from hostd.publishing.mqtt import MqttBridge
from hostd.publishing.mqtt_requests import MAX_PER_CLIENT, MAX_REPLY_BYTES, MAX_REQUEST_BYTES
from hostd.publishing.status import StatusHub
from tui.sources import MqttSource, StatusItem, parse_brokers

MINE = topic("reply/observer-1")


@pytest.fixture
def broker(tmp_path: Path) -> Any:
    running = start_broker(tmp_path / "broker")
    yield running
    running.stop()


def request(name: str, request_id: Any, reply_to: str = MINE, **args: Any) -> str:
    return json.dumps({"req": name, "id": request_id, "reply_to": reply_to, **args})


def replies(observer: Observer, reply_topic: str = MINE) -> list[dict[str, Any]]:
    return [json.loads(item.payload) for item in observer.on(reply_topic)]


def test_read_only_requests_are_answered_on_the_reply_topic_without_allow_commands(
    broker: Broker,
) -> None:
    controller = RecordingController(refuse={"estimate": "no job is printing"})
    bridge = MqttBridge(settings(broker), PRINTER, StatusHub(), controller)  # commands off

    async def body(observer: Observer) -> None:
        await observer.client.subscribe(topic("reply/#"), qos=1)
        # left on the broker, it would be asked again at every reconnect of the daemon
        await observer.client.publish(topic("req"), request("layer", "a5"), qos=1, retain=True)

        async def ask() -> None:
            publish = observer.client.publish
            await publish(topic("req"), request("layer", "a1", layer=3, field=[4, 2]), qos=1)
            await publish(topic("req"), request("estimate", 7), qos=1)
            await publish(topic("req"), request("cancel_object", "a3", object=0), qos=1)
            await publish(topic("req"), json.dumps({"id": "a4", "reply_to": MINE}), qos=1)
            answers = await observer.wait_for(lambda: len(replies(observer)) >= 5
                                              and replies(observer))
            by_id = {answer["id"]: answer for answer in answers}
            assert by_id["a1"] == {"reply": "layer", "ok": True, "id": "a1", "error": None,
                                   "done": "layer"}
            assert by_id[7] == {"reply": "estimate", "ok": False, "id": 7,
                                "error": "no job is printing"}
            # a command is no request: it goes to the cmd topic, where allow_commands rules
            assert not by_id["a3"]["ok"]
            assert "unknown request 'cancel_object'" in by_id["a3"]["error"]
            assert by_id["a4"]["error"] == 'missing "req"'
            assert "retained" in by_id["a5"]["error"]
            assert not any(item.retain for item in observer.on(MINE))
            await publish(topic("req"), b"", qos=1, retain=True)  # clear the retained one

        await with_bridge(bridge, ask)

    asyncio.run(observe(broker, body))
    assert controller.calls == [("layer", {"layer": 3, "field": [4, 2]}), ("estimate", {})]


def test_a_reply_topic_outside_the_printers_reply_topics_is_refused(broker: Broker) -> None:
    controller = RecordingController()
    bridge = MqttBridge(settings(broker), PRINTER, StatusHub(), controller)
    elsewhere = ["hostd/p2/reply/x", topic("reply/a/b"), topic("reply/+"), topic("status"),
                 topic("reply/"), "elsewhere/x", f"{topic('reply/')}{'x' * 65}"]

    async def body(observer: Observer) -> None:
        await observer.client.subscribe("elsewhere/#", qos=1)
        await observer.client.subscribe("hostd/p2/#", qos=1)

        async def ask() -> None:
            await observer.wait_for(lambda: observer.on(topic("status")))
            statuses = len(observer.on(topic("status")))
            publish = observer.client.publish
            await publish(topic("req"), request("layer", "bad", reply_to="elsewhere/x"), qos=1)
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert event["event"] == "error"
            assert event["cmd"] == "layer"
            assert event["id"] == "bad"
            assert f"must be {topic('reply/')}<client>" in event["reason"]
            for number, where in enumerate(elsewhere):
                await publish(topic("req"), request("layer", number, reply_to=where), qos=1)
            await publish(topic("req"), request("layer", "good"), qos=1)
            await observer.wait_for(lambda: replies(observer))  # after every refused one
            assert [answer["id"] for answer in replies(observer)] == ["good"]
            assert observer.on("elsewhere/x") == []
            assert [item.topic for item in observer.messages
                    if item.topic.startswith("hostd/p2/")] == []
            assert len(observer.on(topic("status"))) == statuses  # nothing posed as a status

        await with_bridge(bridge, ask)

    asyncio.run(observe(broker, body))
    assert controller.calls == [("layer", {})]


class LargeReplies(RecordingController):
    """Answers ``layer`` with ``size`` bytes of points."""

    def __init__(self, size: int) -> None:
        super().__init__(refuse={})
        self.size = size

    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        await super().handle(cmd, args)
        return {"points": "x" * self.size}


def test_requests_and_replies_are_bounded_in_size(broker: Broker) -> None:
    controller = LargeReplies(MAX_REPLY_BYTES)
    bridge = MqttBridge(settings(broker), PRINTER, StatusHub(), controller)

    async def body(observer: Observer) -> None:
        async def ask() -> None:
            publish = observer.client.publish
            huge = request("layer", "huge", pad="y" * MAX_REQUEST_BYTES)
            await publish(topic("req"), huge, qos=1)
            event = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert f"larger than {MAX_REQUEST_BYTES} bytes" in event["reason"]
            await publish(topic("req"), request("layer", "big", tolerance=0), qos=1)
            answer = (await observer.wait_for(lambda: replies(observer)))[0]
            assert answer["id"] == "big"
            assert not answer["ok"]
            assert '"tolerance"' in answer["error"]
            assert len(observer.on(MINE)[0].payload) < 1024

        await with_bridge(bridge, ask)

    asyncio.run(observe(broker, body))
    assert controller.calls == [("layer", {"tolerance": 0})]


class Gated(RecordingController):
    """Holds every ``layer`` request until ``gate`` is set (a slow slice)."""

    def __init__(self) -> None:
        super().__init__(refuse={})
        self.gate = asyncio.Event()

    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        if cmd == "layer":
            await self.gate.wait()
        return await super().handle(cmd, args)


def test_a_flood_of_requests_is_told_busy_while_status_and_commands_go_on(
    broker: Broker,
) -> None:
    controller = Gated()
    hub = StatusHub(Snapshot(state="printing"))
    bridge = MqttBridge(settings(broker), PRINTER, hub, controller)
    flood = MAX_PER_CLIENT + 24  # the busy answers all fit the queue of refusals
    theirs = topic("reply/observer-2")

    async def body(observer: Observer) -> None:
        await observer.client.subscribe(topic("reply/#"), qos=1)

        async def ask() -> None:
            await observer.wait_for(lambda: observer.on(topic("status")))
            publish = observer.client.publish
            for number in range(flood):
                await publish(topic("req"), request("layer", number), qos=1)
            # the first ones wait (one is being answered); the rest are told busy at once
            busy = await observer.wait_for(
                lambda: len(replies(observer)) >= flood - MAX_PER_CLIENT and replies(observer))
            assert {answer["ok"] for answer in busy} == {False}
            assert all(answer["error"].startswith("busy") for answer in busy)
            # meanwhile the status, commands and another client's request are served
            hub.update(state="paused")
            await observer.wait_for(
                lambda: (observer.last_json(topic("status")) or {}).get("state") == "paused")
            await publish(topic("cmd"), '{"cmd": "pause", "id": "c1"}', qos=1)
            refused = await observer.wait_for(lambda: observer.last_json(topic("event")))
            assert refused["id"] == "c1"
            await publish(topic("req"), request("layer", "other", reply_to=theirs), qos=1)
            # queued behind the flooder's own (one of them being answered), not told busy
            await until(lambda: bridge.requests.waiting >= MAX_PER_CLIENT,  # (MAX - 1) + 1
                        10, "the other client's request queued", interval=0.01)
            controller.gate.set()
            await observer.wait_for(lambda: replies(observer, theirs))
            answered = await observer.wait_for(
                lambda: len([a for a in replies(observer) if a["ok"]]) == MAX_PER_CLIENT
                and replies(observer))
            assert sorted(a["id"] for a in answered if a["ok"]) == list(range(MAX_PER_CLIENT))
            assert replies(observer, theirs)[0]["ok"]

        await with_bridge(bridge, ask)

    asyncio.run(observe(broker, body))
    assert [cmd for cmd, _args in controller.calls] == ["layer"] * (MAX_PER_CLIENT + 1)


def test_the_fleet_views_requests_cross_a_nats_cluster(tmp_path: Path) -> None:
    """The bridge on one node, the view on another: MQTT 3.1.1 only, QoS 1, no retain."""
    cluster = start_nats_cluster(tmp_path / "nats")
    first, last = cluster.hosts()[0], cluster.hosts()[-1]
    controller = RecordingController(refuse={"estimate": "no job is printing"})
    config = MqttConfig(enabled=True, hosts=tuple(parse_brokers(first)))
    bridge = MqttBridge(config, PRINTER, StatusHub(Snapshot(state="idle")), controller)
    source = MqttSource(parse_brokers(last))

    async def scenario() -> None:
        task = asyncio.create_task(bridge.run())
        seen: list[Any] = []

        async def follow() -> None:
            async for item in source.fleet_stream():
                seen.append(item)

        view = asyncio.create_task(follow())
        try:
            async with asyncio.timeout(30):
                await bridge.connected.wait()
            # the view hears the printer across the cluster
            await until(lambda: any(getattr(item, "printer", "") == PRINTER for item in seen),
                        30, "the printer in the fleet view", interval=0.05)
            source.open_replies(PRINTER)
            reply = await source.query(PRINTER, "layer", layer=2)
            assert reply["done"] == "layer"
            assert reply["id"].startswith(source.token)
            with pytest.raises(ControlError, match="no job is printing"):
                await source.query(PRINTER, "estimate")
            assert not any(isinstance(item, StatusItem) and item.printer != PRINTER
                           for item in seen)  # replies are never taken for a printer
        finally:
            view.cancel()
            task.cancel()
            await asyncio.gather(view, task, return_exceptions=True)

    try:
        asyncio.run(scenario())
    finally:
        cluster.stop()
    assert controller.calls == [("layer", {"layer": 2}), ("estimate", {})]
