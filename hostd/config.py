"""Daemon configuration: TOML to a frozen, fully checked `Config` (unknown keys refused)."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from drivers.linkconfig import LinkSettingError, StreamerConfig
from slicer.fea.material import material_keys, material_settings
from slicer.settings import SettingsError, SliceSettings


class ConfigError(ValueError):
    """A configuration key is unknown or its value is wrong; the message names the key."""

    def __init__(self, key: str, reason: str) -> None:
        super().__init__(f"{key}: {reason}" if key else reason)
        self.key = key
        self.reason = reason


@dataclass(frozen=True)
class JobsConfig:
    """The watched job folder (absolute), settle time in s, size limit in bytes."""

    folder: Path
    settle_s: float = 1.0
    max_bytes: int = 200_000_000


@dataclass(frozen=True)
class StateConfig:
    """Where the job store, the control socket and the logs live (absolute)."""

    folder: Path


@dataclass(frozen=True)
class PrinterConfig:
    """The printer: id for MQTT topics, serial port or "sim", baud, build volume in mm,
    and the link settings (``[printer.link]``)."""

    id: str = "sim"
    port: str = "sim"
    baud: int = 250000
    bed: tuple[float, float, float] = (220.0, 220.0, 250.0)
    link: StreamerConfig = field(default_factory=StreamerConfig)
    material: str = "PLA"  # loaded filament, matched against farm jobs' needs
    nozzle_mm: float = 0.4


@dataclass(frozen=True)
class SimConfig:
    """The built-in simulated printer (port = "sim"): speed factor, emulated wire speed and
    its acceleration (mm/s², which it reports to ``M503`` as a Marlin board does)."""

    time_scale: float = 1.0
    baud: int = 250000
    acceleration: float = 3000.0


@dataclass(frozen=True)
class MqttConfig:
    """The MQTT bridge; off unless ``enabled``."""

    enabled: bool = False
    host: str = "127.0.0.1"
    port: int = 1883
    username: str = ""
    password: str = ""
    tls: bool = False
    ca_file: str = ""
    allow_commands: bool = False
    homeassistant: bool = False
    keepalive: int = 30
    hosts: tuple[tuple[str, int], ...] = ()  # brokers tried in turn; empty: (host, port)

    @property
    def brokers(self) -> tuple[tuple[str, int], ...]:
        """The brokers to connect to, in order: ``hosts``, else ``host`` and ``port``."""
        return self.hosts or ((self.host, self.port),)


@dataclass(frozen=True)
class FarmConfig:
    """The farm queue on a NATS JetStream cluster (``[farm]``); off unless ``enabled``."""

    enabled: bool = False
    servers: tuple[str, ...] = ("nats://127.0.0.1:4222",)
    user: str = ""
    password: str = ""
    tls: bool = False
    ca_file: str = ""
    max_bytes: int = 50_000_000  # largest model a submission may carry
    ack_wait_s: float = 30.0  # a taken job's lease, extended by progress heartbeats


@dataclass(frozen=True)
class RunnerConfig:
    """Just-in-time slicing: layers sliced ahead of the one streaming, and slicing threads."""

    lookahead: int = 4
    workers: int = 2
    # commands a resume goes back from the first one not acknowledged when the printer
    # itself reset: the moves its planner held (Marlin BLOCK_BUFFER_SIZE); the lines of
    # its command buffer were not acknowledged yet, so they are sent again anyway
    replay_lines: int = 16


@dataclass(frozen=True)
class NotifyConfig:
    """Notifications through Apprise URLs (none = off), the events sent, the per-send timeout."""

    urls: tuple[str, ...] = ()
    events: tuple[str, ...] = ("done", "failed", "cancelled", "error", "paused", "first_layer")
    timeout_s: float = 10.0
    picture: bool = True


NOTIFY_EVENTS = ("done", "failed", "cancelled", "error", "paused", "first_layer", "interrupted")


@dataclass(frozen=True)
class Config:
    """The whole daemon configuration."""

    jobs: JobsConfig
    state: StateConfig
    printer: PrinterConfig = field(default_factory=PrinterConfig)
    simulator: SimConfig = field(default_factory=SimConfig)
    mqtt: MqttConfig = field(default_factory=MqttConfig)
    runner: RunnerConfig = field(default_factory=RunnerConfig)
    notify: NotifyConfig = field(default_factory=NotifyConfig)
    farm: FarmConfig = field(default_factory=FarmConfig)
    slicing: SliceSettings = field(default_factory=SliceSettings)
    # the [slicing] keys the file gave (dotted): the others may come from the printer
    slicing_given: frozenset[str] = frozenset()


def load_config(path: str | Path | None = None, cwd: Path | None = None) -> Config:
    """Read and check a TOML configuration file; ``None`` gives the embedded default.

    Relative folders resolve against ``cwd`` (the current directory when omitted).
    Raises ``ConfigError`` naming the offending key.
    """
    data: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as handle:
                data = tomllib.load(handle)
        except OSError as exc:
            raise ConfigError("", f"cannot read {path}: {exc.strerror or exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError("", f"{path} is not valid TOML: {exc}") from exc
    return config_from_mapping(data, cwd or Path.cwd())


def config_from_mapping(data: Mapping[str, Any], cwd: Path) -> Config:
    """Build a `Config` from parsed TOML, refusing unknown sections, keys and bad values."""
    known = {"jobs", "state", "printer", "simulator", "mqtt", "runner", "slicing", "notify",
             "farm", "material"}
    for name, value in data.items():
        if name not in known:
            raise ConfigError(name, "unknown section")
        if not isinstance(value, Mapping):
            raise ConfigError(name, "expected a [table]")
    jobs = _Section(data.get("jobs", {}), "jobs")
    state = _Section(data.get("state", {}), "state")
    printer = _Section(data.get("printer", {}), "printer")
    sim = _Section(data.get("simulator", {}), "simulator")
    mqtt = _Section(data.get("mqtt", {}), "mqtt")
    runner = _Section(data.get("runner", {}), "runner")
    notify = _Section(data.get("notify", {}), "notify")
    farm = _Section(data.get("farm", {}), "farm")
    config = Config(
        jobs=JobsConfig(
            folder=_folder(cwd, jobs.text("folder", "jobs", empty=False)),
            settle_s=jobs.number("settle_s", 1.0, 0.0, 3600.0),
            max_bytes=jobs.integer("max_bytes", 200_000_000, 1, 2**50),
        ),
        state=StateConfig(folder=_folder(cwd, state.text("folder", "var", empty=False))),
        printer=PrinterConfig(
            id=printer.ident("id", "sim"),
            port=printer.text("port", "sim", empty=False),
            baud=printer.integer("baud", 250000, 300, 10_000_000),
            bed=printer.bed("bed", (220.0, 220.0, 250.0)),
            link=printer.link("link"),
            material=printer.text("material", "PLA", empty=False).strip(),
            nozzle_mm=printer.number("nozzle_mm", 0.4, 0.05, 5.0),
        ),
        simulator=SimConfig(
            time_scale=sim.number("time_scale", 1.0, 0.0, 1000.0),
            baud=sim.integer("baud", 250000, 0, 10_000_000),
            acceleration=sim.number("acceleration", 3000.0, 10.0, 100_000.0),
        ),
        mqtt=MqttConfig(
            enabled=mqtt.flag("enabled", False),
            host=mqtt.text("host", "127.0.0.1", empty=False),
            port=mqtt.integer("port", 1883, 1, 65535),
            username=mqtt.text("username", ""),
            password=mqtt.text("password", ""),
            tls=mqtt.flag("tls", False),
            ca_file=mqtt.text("ca_file", ""),
            allow_commands=mqtt.flag("allow_commands", False),
            homeassistant=mqtt.flag("homeassistant", False),
            keepalive=mqtt.integer("keepalive", 30, 5, 3600),
            hosts=_broker_list(mqtt, "hosts", mqtt.values.get("port", 1883)),
        ),
        runner=RunnerConfig(
            lookahead=runner.integer("lookahead", 4, 1, 64),
            workers=runner.integer("workers", 2, 1, 32),
            replay_lines=runner.integer("replay_lines", 16, 0, 10_000),
        ),
        notify=NotifyConfig(
            urls=notify.texts("urls", ()),
            events=notify.choices("events", NotifyConfig.events, NOTIFY_EVENTS),
            timeout_s=notify.number("timeout_s", 10.0, 0.1, 300.0),
            picture=notify.flag("picture", True),
        ),
        farm=FarmConfig(
            enabled=farm.flag("enabled", False),
            servers=farm.texts("servers", FarmConfig.servers),
            user=farm.text("user", ""),
            password=farm.text("password", ""),
            tls=farm.flag("tls", False),
            ca_file=farm.text("ca_file", ""),
            max_bytes=farm.integer("max_bytes", 50_000_000, 1, 2**40),
            ack_wait_s=farm.number("ack_wait_s", 30.0, 1.0, 3600.0),
        ),
        slicing=_anchor_files(_with_material(data, slicing_settings(
            data.get("slicing", {}), None, "slicing")), cwd),
        slicing_given=frozenset(_dotted(data.get("slicing", {})))
        | material_keys(data.get("material", {})),
    )
    for section in (jobs, state, printer, sim, mqtt, runner, notify, farm):
        section.refuse_unknown()
    return config


def _with_material(data: Mapping[str, Any], settings: SliceSettings) -> SliceSettings:
    """``settings`` with the ``[material]`` table's modulus, Poisson's ratio and density."""
    try:
        return material_settings(data.get("material", {}), settings,
                                 frozenset(_dotted(data.get("slicing", {}))))
    except SettingsError as exc:
        raise ConfigError(exc.key, exc.reason) from exc


def slicing_settings(
    values: Mapping[str, Any], base: SliceSettings | None, prefix: str
) -> SliceSettings:
    """Slicing settings from (nested or dotted) keys; errors name ``prefix.key``."""
    try:
        return SliceSettings.from_mapping(values, base=base)
    except SettingsError as exc:
        raise ConfigError(f"{prefix}.{exc.key}" if prefix else exc.key, exc.reason) from exc


def _dotted(values: Mapping[str, Any], prefix: str = "") -> list[str]:
    """The dotted keys of a (nested) table: ``{"infill": {"density": 0.3}}`` gives
    ``["infill.density"]``."""
    keys = []
    for key, value in values.items():
        if isinstance(value, Mapping):
            keys += _dotted(value, f"{prefix}{key}.")
        else:
            keys.append(f"{prefix}{key}")
    return keys


def _anchor_files(settings: SliceSettings, cwd: Path) -> SliceSettings:
    """A relative ``infill.file`` made absolute against ``cwd``, as the folders are, so
    that it names the same file whatever the daemon's working directory later."""
    if not settings.infill_file:
        return settings
    path = _folder(cwd, settings.infill_file)
    return replace(settings, infill_file=str(path))


def _broker_list(section: _Section, key: str, default_port: Any) -> tuple[tuple[str, int], ...]:
    """``hosts = ["host[:port]", ...]`` as (host, port) pairs; a missing port is ``port``."""
    value = section._get(key, [])
    if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
        raise section._fail(key, f'expected a list of "host[:port]" strings, got {value!r}')
    found = []
    for item in value:
        host, colon, port = item.strip().rpartition(":")
        if not colon:
            host, port = item.strip(), str(default_port)
        if not host or any(ch.isspace() or ch in "/[]" for ch in host):
            raise section._fail(key, f"{item!r} is not host or host:port")
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            raise section._fail(key, f"{item!r}: the port must be a number in 1..65535")
        found.append((host, int(port)))
    return tuple(found)


def _folder(cwd: Path, text: str) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else (cwd / path).absolute()


class _Section:
    """One TOML table being read: typed getters that remember which keys were used."""

    def __init__(self, values: Mapping[str, Any], name: str) -> None:
        self.values = values
        self.name = name
        self.used: set[str] = set()

    def _get(self, key: str, default: Any) -> Any:
        self.used.add(key)
        return self.values.get(key, default)

    def _fail(self, key: str, reason: str) -> ConfigError:
        return ConfigError(f"{self.name}.{key}", reason)

    def refuse_unknown(self) -> None:
        for key in self.values:
            if key not in self.used:
                raise self._fail(key, "unknown key")

    def text(self, key: str, default: str, empty: bool = True) -> str:
        value = self._get(key, default)
        if not isinstance(value, str):
            raise self._fail(key, f"expected a string, got {value!r}")
        if not empty and not value.strip():
            raise self._fail(key, "must not be empty")
        return value

    def ident(self, key: str, default: str) -> str:
        value = self.text(key, default, empty=False)
        if any(ch in value for ch in "/#+ \t\n") or not value.isprintable():
            raise self._fail(key, f"{value!r} may not contain spaces, '/', '#' or '+'")
        return value

    def texts(self, key: str, default: tuple[str, ...]) -> tuple[str, ...]:
        value = self._get(key, list(default))
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise self._fail(key, f"expected a list of strings, got {value!r}")
        for item in value:
            if not item.strip():
                raise self._fail(key, "an entry is empty")
        return tuple(value)

    def choices(
        self, key: str, default: tuple[str, ...], allowed: tuple[str, ...]
    ) -> tuple[str, ...]:
        value = self.texts(key, default)
        for item in value:
            if item not in allowed:
                raise self._fail(key, f"unknown {item!r}; choose from {', '.join(allowed)}")
        return value

    def flag(self, key: str, default: bool) -> bool:
        value = self._get(key, default)
        if not isinstance(value, bool):
            raise self._fail(key, f"expected true or false, got {value!r}")
        return value

    def number(self, key: str, default: float, low: float, high: float) -> float:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self._fail(key, f"expected a number, got {value!r}")
        if not math.isfinite(value):
            raise self._fail(key, "must be finite")
        if not low <= value <= high:
            raise self._fail(key, f"{value!r} is outside {low:g}..{high:g}")
        return float(value)

    def integer(self, key: str, default: int, low: int, high: int) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._fail(key, f"expected a whole number, got {value!r}")
        if not low <= value <= high:
            raise self._fail(key, f"{value!r} is outside {low}..{high}")
        return value

    def link(self, key: str) -> StreamerConfig:
        value = self._get(key, {})
        if not isinstance(value, Mapping):
            raise self._fail(key, "expected a [table]")
        try:
            return StreamerConfig.from_mapping(value)
        except LinkSettingError as exc:
            raise self._fail(f"{key}.{exc.key}", exc.reason) from exc

    def bed(self, key: str, default: tuple[float, float, float]) -> tuple[float, float, float]:
        value = self._get(key, list(default))
        if not isinstance(value, list) or len(value) != 3:
            raise self._fail(key, f"expected [x, y, z] in mm, got {value!r}")
        out = []
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int | float):
                raise self._fail(key, f"expected numbers, got {item!r}")
            if not math.isfinite(item) or not 1.0 <= item <= 10_000.0:
                raise self._fail(key, f"{item!r} is outside 1..10000 mm")
            out.append(float(item))
        return (out[0], out[1], out[2])
