"""Home Assistant as a device: discovery on a real broker checked against its rules; a daemon."""

from __future__ import annotations

import asyncio
import datetime
import io
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import aiomqtt
import pytest
import trimesh
from PIL import Image
from support.brokers import HOST, Broker, start_broker
from support.doubles import RecordingController
from support.paths import ROOT
from support.waiting import until

from hostd.api import JobStatus, Snapshot, Temperature, Temps
from hostd.config import MqttConfig
from hostd.publishing.homeassistant import DeviceTopics, device_config, node_id
from hostd.publishing.mqtt import MqttBridge
from hostd.publishing.status import StatusHub

jinja2 = pytest.importorskip("jinja2")

PRINTER = "mk3-left"
USER, SECRET = "ha", "pw-ha"
NODE = node_id(PRINTER)
DEVICE_TOPIC = f"homeassistant/device/{NODE}/config"
LEGACY = ("state", "progress", "layer", "eta", "hotend", "bed")

# Home Assistant's MQTT options per platform (the ones this discovery may use) and the
# required ones; device-based discovery also requires ``p`` and ``unique_id`` per component.
COMMON = {"p", "name", "unique_id", "icon", "availability_topic", "payload_available",
          "payload_not_available", "qos"}
PLATFORMS = {
    "sensor": (COMMON | {"state_topic", "value_template", "unit_of_measurement", "device_class",
                         "state_class"}, {"state_topic"}),
    "button": (COMMON | {"command_topic", "payload_press"}, {"command_topic"}),
    "image": (COMMON | {"image_topic", "content_type", "image_encoding"}, {"image_topic"}),
}
ROOT_KEYS = {"dev", "o", "cmps", "availability_topic", "payload_available",
             "payload_not_available", "qos"}
SENSOR_CLASSES = {"temperature": {"°C"}, "duration": {"s"}, "timestamp": {None},
                  "distance": {"mm"}}


def check_discovery(config: dict[str, Any], commands: bool) -> dict[str, dict[str, Any]]:
    """Assert Home Assistant's rules for a device discovery payload; its components by key."""
    assert set(config) <= ROOT_KEYS, set(config) - ROOT_KEYS
    assert config["dev"]["ids"] == [NODE]
    assert config["dev"]["name"]
    assert config["o"]["name"] == "hostd"
    assert config["o"]["sw"]
    assert config["availability_topic"] == f"hostd/{PRINTER}/online"
    assert (config["payload_available"], config["payload_not_available"]) == ("online", "offline")
    components = config["cmps"]
    unique = [c["unique_id"] for c in components.values()]
    assert len(unique) == len(set(unique)), "unique ids must be unique"
    for key, component in components.items():
        allowed, required = PLATFORMS[component["p"]]
        assert set(component) <= allowed, (key, set(component) - allowed)
        assert required <= set(component), (key, required - set(component))
        assert component["unique_id"].startswith(NODE)
        if component["p"] == "sensor" and "device_class" in component:
            assert component.get("unit_of_measurement") in SENSOR_CLASSES[component["device_class"]]
            if component["device_class"] == "timestamp":
                assert "state_class" not in component
        if component["p"] == "button":
            assert component["command_topic"] == f"hostd/{PRINTER}/cmd"
            assert json.loads(component["payload_press"])["cmd"] in ("pause", "resume", "cancel")
        if component["p"] == "image":
            assert component["content_type"] == "image/png"
    buttons = {c["name"] for c in components.values() if c["p"] == "button"}
    assert buttons == ({"Pause", "Resume", "Cancel"} if commands else set())
    return {key.removeprefix(f"{NODE}_"): component for key, component in components.items()}


def timestamp_custom(value: float, fmt: str, local: bool = True) -> str:
    """Home Assistant's ``timestamp_custom`` filter."""
    zone = None if local else datetime.UTC
    return datetime.datetime.fromtimestamp(value, zone).strftime(fmt)


def render(template: str, payload: dict[str, Any]) -> str:
    """Render a value template as Home Assistant does: ``value_json`` is the payload."""
    env = jinja2.Environment()
    env.filters["timestamp_custom"] = timestamp_custom
    return env.from_string(template).render(value_json=payload)


def test_device_discovery_replaces_the_old_configs_and_follows_home_assistant(
    tmp_path: Path,
) -> None:
    broker = start_broker(tmp_path / "broker", users={USER: SECRET})
    hub = StatusHub(Snapshot(state="idle"))
    controller = RecordingController()
    config = MqttConfig(enabled=True, host=HOST, port=broker.port, homeassistant=True,
                        username=USER, password=SECRET, allow_commands=True)
    bridge = MqttBridge(config, PRINTER, hub, controller)

    async def main() -> tuple[list[aiomqtt.Message], list[aiomqtt.Message], dict[str, Any]]:
        async with aiomqtt.Client(HOST, broker.port, username=USER, password=SECRET) as client:
            for key in LEGACY:  # what an older version left retained
                await client.publish(f"homeassistant/sensor/{NODE}_{key}/config", "{}",
                                     qos=1, retain=True)
            await client.subscribe("homeassistant/#", qos=1)
            task = asyncio.create_task(bridge.run())
            seen: list[aiomqtt.Message] = []
            async with asyncio.timeout(10):
                async for message in client.messages:
                    seen.append(message)
                    if str(message.topic) == DEVICE_TOPIC:
                        break
            # Home Assistant restarts: it says so, and the device is announced again
            await client.publish("homeassistant/status", "online", qos=1)
            again: list[aiomqtt.Message] = []
            async with asyncio.timeout(10):
                async for message in client.messages:
                    again.append(message)
                    if str(message.topic) == DEVICE_TOPIC:
                        break
            button = check_discovery(json.loads(again[-1].payload), True)["pause"]
            await client.publish(button["command_topic"], button["payload_press"], qos=1)
            await until(lambda: controller.commands, 10, "the button's command")
        async with aiomqtt.Client(HOST, broker.port, username=USER, password=SECRET) as fresh:
            await fresh.subscribe("homeassistant/#", qos=1)
            retained: dict[str, Any] = {}
            with pytest.raises(TimeoutError):
                async with asyncio.timeout(1.0):
                    async for message in fresh.messages:
                        retained[str(message.topic)] = message.payload
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return seen, again, retained

    try:
        seen, again, retained = asyncio.run(main())
    finally:
        broker.stop()
    legacy = {f"homeassistant/sensor/{NODE}_{key}/config" for key in LEGACY}
    removals = [m for m in seen if str(m.topic) in legacy and m.payload == b""]
    assert {str(m.topic) for m in removals} == legacy  # removed before the device came
    assert [str(m.topic) for m in seen][-1] == DEVICE_TOPIC
    components = check_discovery(json.loads(seen[-1].payload), True)
    assert {"state", "job", "progress", "layer", "layers", "eta", "finish", "hotend", "bed",
            "filament", "layer_image", "pause", "resume", "cancel"} == set(components)
    assert json.loads(again[-1].payload) == json.loads(seen[-1].payload)
    assert controller.commands == ["pause"]
    assert set(retained) == {DEVICE_TOPIC}  # the old configs are gone from the broker


def test_no_buttons_without_commands_and_templates_read_the_status() -> None:
    topics = DeviceTopics.for_printer(PRINTER)
    components = check_discovery(device_config(PRINTER, topics, commands=False), False)
    templates = {key: c["value_template"] for key, c in components.items() if c["p"] == "sensor"}
    printing = Snapshot(
        state="printing",
        temps=Temps(hotend=Temperature(209.6, 210.0), bed=Temperature(59.9, 60.0)),
        job=JobStatus(id="4", name="bunny.stl", layer=17, layers=120, progress=0.1416,
                      eta_s=1234.4),
        ts=1_800_000_000.0,
    ).to_dict()
    assert render(templates["state"], printing) == "printing"
    assert render(templates["job"], printing) == "bunny.stl"
    assert render(templates["progress"], printing) == "14.2"
    assert render(templates["layer"], printing) == "18"
    assert render(templates["layers"], printing) == "18 / 120"
    assert render(templates["eta"], printing) == "1234.0"
    finish = datetime.datetime.fromisoformat(render(templates["finish"], printing))
    assert finish.timestamp() == pytest.approx(1_800_000_000.0 + 1234.4, abs=1)
    assert render(templates["hotend"], printing) == "209.6"
    assert render(templates["bed"], printing) == "59.9"
    assert render(templates["filament"], {"filament_mm": 1234.56}) == "1235.0"
    assert components["filament"]["state_topic"] == f"hostd/{PRINTER}/job"
    idle = Snapshot(state="idle").to_dict()
    for key in ("job", "progress", "layer", "layers", "eta", "finish"):  # "unknown" in HA
        assert render(templates[key], idle) == "None"
    no_eta = {**printing, "job": {**printing["job"], "eta_s": None}}
    assert render(templates["eta"], no_eta) == render(templates["finish"], no_eta) == "None"


def test_a_daemon_publishes_the_layer_picture_the_job_figures_and_the_history(
    tmp_path: Path,
) -> None:
    broker = start_broker(tmp_path / "broker")
    (tmp_path / "hostd.toml").write_text(
        "[jobs]\nfolder = \"jobs\"\nsettle_s = 0.2\n[state]\nfolder = \"var\"\n"
        f"[printer]\nid = \"{PRINTER}\"\n[simulator]\ntime_scale = 0\nbaud = 0\n"
        f"[mqtt]\nenabled = true\nhost = \"{HOST}\"\nport = {broker.port}\nhomeassistant = true\n"
    )
    daemon = subprocess.Popen(
        [sys.executable, "-c", "import sys; from hostd.app.cli import main; sys.exit(main())",
         "run", "--config", str(tmp_path / "hostd.toml")],
        cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        retained = asyncio.run(_print_and_collect(broker, tmp_path))
    finally:
        daemon.terminate()
        daemon.wait(20)
        broker.stop()
    config = json.loads(retained[DEVICE_TOPIC])
    components = check_discovery(config, False)  # no credentials: no buttons
    image = Image.open(io.BytesIO(retained[components["layer_image"]["image_topic"]]))
    assert image.format == "PNG"
    assert max(image.size) == 480
    job = json.loads(retained[f"hostd/{PRINTER}/job"])
    header = (tmp_path / "jobs" / "done" / "cube.gcode").read_text().splitlines()[:20]
    slicer_mm = float(next(line for line in header if "filament used [mm]" in line).split()[-1])
    assert job["name"] == "cube.stl"
    assert job["completed"] == job["layers"] - 1 == 24
    assert abs(job["filament_mm"] - slicer_mm) <= 6  # the end's retraction is not a layer's
    history = json.loads(retained[f"hostd/{PRINTER}/history"])
    assert history["totals"]["jobs"] == 1
    assert history["last"][0]["outcome"] == "done"


async def _print_and_collect(broker: Broker, folder: Path) -> dict[str, bytes]:
    """Drop a 20 x 20 x 5 mm box once the daemon is online; the retained topics once the
    history has it."""
    retained: dict[str, bytes] = {}
    async with aiomqtt.Client(HOST, broker.port) as client:
        await client.subscribe(f"hostd/{PRINTER}/#", qos=1)
        await client.subscribe("homeassistant/#", qos=1)
        async with asyncio.timeout(90):
            async for message in client.messages:
                topic = str(message.topic)
                retained[topic] = message.payload
                if topic.endswith("/online") and message.payload == b"online":
                    (folder / "jobs").mkdir(exist_ok=True)
                    hidden = folder / "jobs" / ".cube.stl.part"
                    trimesh.creation.box((20.0, 20.0, 5.0)).export(hidden, file_type="stl")
                    os.replace(folder / "jobs" / ".cube.stl.part", folder / "jobs" / "cube.stl")
                if topic.endswith("/history") and json.loads(message.payload)["totals"]["jobs"]:
                    return retained
    raise AssertionError("unreachable")
