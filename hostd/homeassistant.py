"""Home Assistant MQTT discovery: the retained sensor configs that describe one printer."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

from hostd import __version__

DISCOVERY_PREFIX = "homeassistant"


@dataclass(frozen=True)
class Sensor:
    """One sensor read from the status JSON by a Home Assistant value template."""

    key: str
    name: str
    template: str
    unit: str | None = None
    device_class: str | None = None
    state_class: str | None = None
    icon: str | None = None


# Templates render ``None`` (Home Assistant's "unknown") when there is no job.
SENSORS = (
    Sensor("state", "State", "{{ value_json.state }}", icon="mdi:printer-3d"),
    Sensor(
        "progress", "Progress",
        "{{ (value_json.job.progress * 100) | round(1) if value_json.job else None }}",
        unit="%", state_class="measurement", icon="mdi:progress-clock",
    ),
    Sensor(
        "layer", "Layer",
        "{{ value_json.job.layer if value_json.job else None }}",
        state_class="measurement", icon="mdi:layers-triple",
    ),
    Sensor(
        "eta", "Time remaining",
        "{{ value_json.job.eta_s | round(0) if value_json.job and value_json.job.eta_s"
        " is not none else None }}",
        unit="s", device_class="duration",
    ),
    Sensor(
        "hotend", "Hotend temperature", "{{ value_json.temps.hotend.actual }}",
        unit="°C", device_class="temperature", state_class="measurement",
    ),
    Sensor(
        "bed", "Bed temperature", "{{ value_json.temps.bed.actual }}",
        unit="°C", device_class="temperature", state_class="measurement",
    ),
)


def node_id(printer_id: str) -> str:
    """The printer id reduced to the characters Home Assistant allows in topic ids."""
    return "hostd_" + re.sub(r"[^A-Za-z0-9_-]", "_", printer_id)


def discovery_messages(
    printer_id: str, status_topic: str, online_topic: str
) -> list[tuple[str, str]]:
    """``(topic, payload)`` of every sensor config, to be published retained.

    Topics are ``homeassistant/sensor/hostd_<id>_<name>/config``; every sensor
    reads ``status_topic`` and is available while ``online_topic`` says ``online``.
    """
    node = node_id(printer_id)
    device = {
        "identifiers": [node],
        "name": f"hostd {printer_id}",
        "manufacturer": "hostd",
        "model": "3D-printer host",
        "sw_version": __version__,
    }
    messages = []
    for sensor in SENSORS:
        config: dict[str, object] = {
            "name": sensor.name,
            "unique_id": f"{node}_{sensor.key}",
            "object_id": f"{node}_{sensor.key}",
            "state_topic": status_topic,
            "value_template": sensor.template,
            "availability_topic": online_topic,
            "payload_available": "online",
            "payload_not_available": "offline",
            "device": device,
        }
        optional = {
            "unit_of_measurement": sensor.unit,
            "device_class": sensor.device_class,
            "state_class": sensor.state_class,
            "icon": sensor.icon,
        }
        config.update({key: value for key, value in optional.items() if value is not None})
        topic = f"{DISCOVERY_PREFIX}/sensor/{node}_{sensor.key}/config"
        messages.append((topic, json.dumps(config, sort_keys=True, ensure_ascii=False)))
    return messages
