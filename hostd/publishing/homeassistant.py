"""Home Assistant MQTT discovery: the printer as one device with its entities and their topics."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from hostd import __version__

DISCOVERY_PREFIX = "homeassistant"
HA_STATUS_TOPIC = f"{DISCOVERY_PREFIX}/status"  # Home Assistant says "online" here when it starts
ORIGIN = {"name": "hostd", "sw": __version__}

# the per-sensor configs published before the device discovery; removed once per connection
LEGACY_SENSORS = ("state", "progress", "layer", "eta", "hotend", "bed")
BUTTONS = (("pause", "Pause", "mdi:pause"), ("resume", "Resume", "mdi:play"),
           ("cancel", "Cancel", "mdi:stop"))


@dataclass(frozen=True)
class Sensor:
    """One sensor read by a Home Assistant value template from a JSON topic."""

    key: str
    name: str
    template: str
    unit: str | None = None
    device_class: str | None = None
    state_class: str | None = None
    icon: str | None = None
    topic: str = "status"  # "status" (the snapshot) or "job" (the job tracker's figures)


# Templates render ``None`` (Home Assistant's "unknown") when there is no job.
_JOB = "value_json.job"
SENSORS = (
    Sensor("state", "State", "{{ value_json.state }}", icon="mdi:printer-3d"),
    Sensor("job", "Job", f"{{{{ {_JOB}.name if {_JOB} else None }}}}", icon="mdi:file-cad"),
    Sensor(
        "progress", "Progress",
        f"{{{{ ({_JOB}.progress * 100) | round(1) if {_JOB} else None }}}}",
        unit="%", state_class="measurement", icon="mdi:progress-clock",
    ),
    Sensor(
        "layer", "Layer",
        f"{{{{ {_JOB}.layer + 1 if {_JOB} else None }}}}",
        state_class="measurement", icon="mdi:layers-triple",
    ),
    Sensor(
        "layers", "Layer of layers",
        f"{{{{ '%d / %d' % ({_JOB}.layer + 1, {_JOB}.layers) if {_JOB} else None }}}}",
        icon="mdi:layers-outline",
    ),
    Sensor(
        "eta", "Time remaining",
        f"{{{{ {_JOB}.eta_s | round(0) if {_JOB} and {_JOB}.eta_s is not none else None }}}}",
        unit="s", device_class="duration",
    ),
    Sensor(
        "finish", "Finish time",
        f"{{{{ (value_json.ts + {_JOB}.eta_s) | timestamp_custom('%Y-%m-%dT%H:%M:%S+00:00',"
        f" false) if {_JOB} and {_JOB}.eta_s is not none else None }}}}",
        device_class="timestamp", icon="mdi:clock-end",
    ),
    Sensor(
        "hotend", "Hotend temperature", "{{ value_json.temps.hotend.actual }}",
        unit="°C", device_class="temperature", state_class="measurement",
    ),
    Sensor(
        "bed", "Bed temperature", "{{ value_json.temps.bed.actual }}",
        unit="°C", device_class="temperature", state_class="measurement",
    ),
    Sensor(
        "filament", "Filament used", "{{ value_json.filament_mm | round(0) }}",
        unit="mm", device_class="distance", state_class="measurement", icon="mdi:printer-3d-nozzle",
        topic="job",
    ),
)


@dataclass(frozen=True)
class DeviceTopics:
    """The printer's topics that the discovery names."""

    status: str
    online: str
    cmd: str
    job: str
    image: str

    @classmethod
    def for_printer(cls, printer_id: str) -> DeviceTopics:
        base = f"hostd/{printer_id}"
        return cls(f"{base}/status", f"{base}/online", f"{base}/cmd", f"{base}/job",
                   f"{base}/layer_image")


def node_id(printer_id: str) -> str:
    """The printer id reduced to the characters Home Assistant allows in topic ids."""
    return "hostd_" + re.sub(r"[^A-Za-z0-9_-]", "_", printer_id)


def device_config(printer_id: str, topics: DeviceTopics, commands: bool) -> dict[str, object]:
    """The device discovery payload: device ``dev``, origin ``o``, components ``cmps``.

    Every component is available while ``topics.online`` says ``online``;
    the buttons (pause, resume, cancel) are there only when ``commands``.
    """
    node = node_id(printer_id)
    components: dict[str, dict[str, object]] = {}
    for sensor in SENSORS:
        component: dict[str, object] = {
            "p": "sensor",
            "name": sensor.name,
            "unique_id": f"{node}_{sensor.key}",
            "state_topic": topics.job if sensor.topic == "job" else topics.status,
            "value_template": sensor.template,
        }
        optional = {
            "unit_of_measurement": sensor.unit,
            "device_class": sensor.device_class,
            "state_class": sensor.state_class,
            "icon": sensor.icon,
        }
        component.update({key: value for key, value in optional.items() if value is not None})
        components[f"{node}_{sensor.key}"] = component
    if commands:
        for key, name, icon in BUTTONS:
            components[f"{node}_{key}"] = {
                "p": "button",
                "name": name,
                "unique_id": f"{node}_{key}",
                "command_topic": topics.cmd,
                "payload_press": json.dumps({"cmd": key}),
                "icon": icon,
            }
    components[f"{node}_layer_image"] = {
        "p": "image",
        "name": "Layer being printed",
        "unique_id": f"{node}_layer_image",
        "image_topic": topics.image,
        "content_type": "image/png",
    }
    return {
        "dev": {
            "ids": [node],
            "name": f"hostd {printer_id}",
            "mf": "hostd",
            "mdl": "3D-printer host",
            "sw": __version__,
        },
        "o": dict(ORIGIN),
        "cmps": components,
        "availability_topic": topics.online,
        "payload_available": "online",
        "payload_not_available": "offline",
        "qos": 1,
    }


def discovery_messages(
    printer_id: str, topics: DeviceTopics, commands: bool
) -> list[tuple[str, str]]:
    """``(topic, payload)`` to publish retained, in order, at each connection.

    First an empty payload on each old per-sensor config topic (Home Assistant
    removes those entities, so their unique ids are free again), then the one
    ``homeassistant/device/<node>/config``.
    """
    node = node_id(printer_id)
    messages = [(f"{DISCOVERY_PREFIX}/sensor/{node}_{key}/config", "") for key in LEGACY_SENSORS]
    payload = json.dumps(device_config(printer_id, topics, commands), sort_keys=True,
                         ensure_ascii=False)
    messages.append((f"{DISCOVERY_PREFIX}/device/{node}/config", payload))
    return messages
