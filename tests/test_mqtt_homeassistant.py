"""Home Assistant discovery: retained configs on a real broker whose templates read the status."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
from brokers import HOST, start_broker

from hostd.api import JobStatus, Snapshot, Temperature, Temps
from hostd.config import MqttConfig
from hostd.homeassistant import discovery_messages, node_id
from hostd.mqtt import MqttBridge
from hostd.status import StatusHub

jinja2 = pytest.importorskip("jinja2")

PRINTER = "mk3-left"
EXPECTED = {"state", "progress", "layer", "eta", "hotend", "bed"}


class Controller:
    async def handle(self, cmd: str, args: dict[str, Any]) -> dict[str, Any]:
        return {}


def render(template: str, status: dict[str, Any]) -> str:
    """Render a value template the way Home Assistant does: ``value_json`` is the payload."""
    return jinja2.Environment().from_string(template).render(value_json=status)


def test_discovery_configs_are_published_retained(tmp_path: Path) -> None:
    broker = start_broker(tmp_path / "broker")
    hub = StatusHub(Snapshot(state="idle"))
    config = MqttConfig(enabled=True, host=HOST, port=broker.port, homeassistant=True)
    bridge = MqttBridge(config, PRINTER, hub, Controller())

    async def main() -> dict[str, dict[str, Any]]:
        task = asyncio.create_task(bridge.run())
        async with asyncio.timeout(10):
            await bridge.connected.wait()
        configs: dict[str, dict[str, Any]] = {}
        async with aiomqtt.Client(HOST, broker.port) as client:
            await client.subscribe("homeassistant/#")
            async with asyncio.timeout(10):
                async for message in client.messages:
                    assert message.retain, "discovery configs must be retained"
                    configs[str(message.topic)] = json.loads(message.payload)
                    if len(configs) == len(EXPECTED):
                        break
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return configs

    try:
        configs = asyncio.run(main())
    finally:
        broker.stop()
    node = node_id(PRINTER)
    assert node == "hostd_mk3-left"
    assert set(configs) == {f"homeassistant/sensor/{node}_{key}/config" for key in EXPECTED}
    for key in EXPECTED:
        config = configs[f"homeassistant/sensor/{node}_{key}/config"]
        assert config["unique_id"] == f"{node}_{key}"
        assert config["state_topic"] == f"hostd/{PRINTER}/status"
        assert config["availability_topic"] == f"hostd/{PRINTER}/online"
        assert (config["payload_available"], config["payload_not_available"]) == (
            "online", "offline"
        )
        assert config["device"]["identifiers"] == [node]
    assert configs[f"homeassistant/sensor/{node}_hotend/config"]["device_class"] == "temperature"
    assert configs[f"homeassistant/sensor/{node}_eta/config"]["unit_of_measurement"] == "s"


def test_value_templates_read_the_status_snapshot() -> None:
    templates = {
        json.loads(payload)["unique_id"].rsplit("_", 1)[1]: json.loads(payload)["value_template"]
        for _, payload in discovery_messages("sim", "hostd/sim/status", "hostd/sim/online")
    }
    printing = Snapshot(
        state="printing",
        temps=Temps(hotend=Temperature(209.6, 210.0), bed=Temperature(59.9, 60.0)),
        job=JobStatus(id="4", name="bunny.stl", layer=17, layers=120, progress=0.1416,
                      eta_s=1234.4),
    ).to_dict()
    assert render(templates["state"], printing) == "printing"
    assert render(templates["progress"], printing) == "14.2"
    assert render(templates["layer"], printing) == "17"
    assert render(templates["eta"], printing) == "1234.0"
    assert render(templates["hotend"], printing) == "209.6"
    assert render(templates["bed"], printing) == "59.9"
    idle = Snapshot(state="idle").to_dict()
    # no job: Home Assistant shows "unknown" for a rendered None
    for key in ("progress", "layer", "eta"):
        assert render(templates[key], idle) == "None"
    no_eta = {**printing, "job": {**printing["job"], "eta_s": None}}
    assert render(templates["eta"], no_eta) == "None"
