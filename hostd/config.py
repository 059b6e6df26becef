"""Daemon configuration: TOML to a frozen, fully checked `Config` (unknown keys refused)."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from slicer.fea.material import material_keys, material_settings
from slicer.options import Flag, Number, SettingError, Table, Text, Texts, Whole
from slicer.settings import SliceSettings

if TYPE_CHECKING:
    from drivers.link.config import StreamerConfig

# the one settings error (``slicer.options``), by the name the configuration has always used
ConfigError = SettingError


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
    # ``[printer.link]`` as given, checked; None when not given (the link's defaults,
    # made on first use: a command that never opens the link does not load its module)
    link_given: StreamerConfig | None = None
    material: str = "PLA"  # loaded filament, matched against farm jobs' needs
    nozzle_mm: float = 0.4

    @property
    def link(self) -> StreamerConfig:
        """The printer link's settings (``[printer.link]``, or the link's defaults)."""
        if self.link_given is not None:
            return self.link_given
        from drivers.link.config import StreamerConfig

        return StreamerConfig()


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
    # slice each print's layers in a process of its own, ended with the print, so that
    # what slicing leaves in a heap goes back to the system (see slicer.planprocess)
    slice_process: bool = True


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
    Raises ``SettingError`` (``ConfigError``) naming the offending key.
    """
    data: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as handle:
                data = tomllib.load(handle)
        except OSError as exc:
            raise SettingError("", f"cannot read {path}: {exc.strerror or exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise SettingError("", f"{path} is not valid TOML: {exc}") from exc
    return config_from_mapping(data, cwd or Path.cwd())


def config_from_mapping(data: Mapping[str, Any], cwd: Path) -> Config:
    """Build a `Config` from parsed TOML, refusing unknown sections, keys and bad values."""
    known = {"jobs", "state", "printer", "simulator", "mqtt", "runner", "slicing", "notify",
             "farm", "material"}
    for name, value in data.items():
        if name not in known:
            raise SettingError(name, "unknown section")
        if not isinstance(value, Mapping):
            raise SettingError(name, "expected a [table]")
    jobs = Table(data.get("jobs", {}), "jobs")
    state = Table(data.get("state", {}), "state")
    printer = Table(data.get("printer", {}), "printer")
    sim = Table(data.get("simulator", {}), "simulator")
    mqtt = Table(data.get("mqtt", {}), "mqtt")
    runner = Table(data.get("runner", {}), "runner")
    notify = Table(data.get("notify", {}), "notify")
    farm = Table(data.get("farm", {}), "farm")
    config = Config(
        jobs=JobsConfig(
            folder=_folder(cwd, jobs.get("folder", Text(empty=False), "jobs")),
            settle_s=jobs.get("settle_s", Number(0.0, 3600.0), 1.0),
            max_bytes=jobs.get("max_bytes", Whole(1, 2**50), 200_000_000),
        ),
        state=StateConfig(folder=_folder(cwd, state.get("folder", Text(empty=False), "var"))),
        printer=PrinterConfig(
            id=_ident(printer, "id", "sim"),
            port=printer.get("port", Text(empty=False), "sim"),
            baud=printer.get("baud", Whole(300, 10_000_000), 250000),
            bed=_bed(printer, "bed", (220.0, 220.0, 250.0)),
            link_given=_link(printer, "link"),
            material=printer.get("material", Text(empty=False), "PLA").strip(),
            nozzle_mm=printer.get("nozzle_mm", Number(0.05, 5.0), 0.4),
        ),
        simulator=SimConfig(
            time_scale=sim.get("time_scale", Number(0.0, 1000.0), 1.0),
            baud=sim.get("baud", Whole(0, 10_000_000), 250000),
            acceleration=sim.get("acceleration", Number(10.0, 100_000.0), 3000.0),
        ),
        mqtt=MqttConfig(
            enabled=mqtt.get("enabled", Flag(), False),
            host=mqtt.get("host", Text(empty=False), "127.0.0.1"),
            port=mqtt.get("port", Whole(1, 65535), 1883),
            username=mqtt.get("username", Text(), ""),
            password=mqtt.get("password", Text(), ""),
            tls=mqtt.get("tls", Flag(), False),
            ca_file=mqtt.get("ca_file", Text(), ""),
            allow_commands=mqtt.get("allow_commands", Flag(), False),
            homeassistant=mqtt.get("homeassistant", Flag(), False),
            keepalive=mqtt.get("keepalive", Whole(5, 3600), 30),
            hosts=_broker_list(mqtt, "hosts", mqtt.values.get("port", 1883)),
        ),
        runner=RunnerConfig(
            lookahead=runner.get("lookahead", Whole(1, 64), 4),
            workers=runner.get("workers", Whole(1, 32), 2),
            replay_lines=runner.get("replay_lines", Whole(0, 10_000), 16),
            slice_process=runner.get("slice_process", Flag(), True),
        ),
        notify=NotifyConfig(
            urls=notify.get("urls", _ENTRIES, ()),
            events=notify.get("events", Texts(empty_items=False, choices=NOTIFY_EVENTS),
                              NotifyConfig.events),
            timeout_s=notify.get("timeout_s", Number(0.1, 300.0), 10.0),
            picture=notify.get("picture", Flag(), True),
        ),
        farm=FarmConfig(
            enabled=farm.get("enabled", Flag(), False),
            servers=farm.get("servers", _ENTRIES, FarmConfig.servers),
            user=farm.get("user", Text(), ""),
            password=farm.get("password", Text(), ""),
            tls=farm.get("tls", Flag(), False),
            ca_file=farm.get("ca_file", Text(), ""),
            max_bytes=farm.get("max_bytes", Whole(1, 2**40), 50_000_000),
            ack_wait_s=farm.get("ack_wait_s", Number(1.0, 3600.0), 30.0),
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
    return material_settings(data.get("material", {}), settings,
                             frozenset(_dotted(data.get("slicing", {}))))


def slicing_settings(
    values: Mapping[str, Any], base: SliceSettings | None, prefix: str
) -> SliceSettings:
    """Slicing settings from (nested or dotted) keys; errors name ``prefix.key``."""
    try:
        return SliceSettings.from_mapping(values, base=base)
    except SettingError as exc:
        raise exc.within(prefix) from exc


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


def _broker_list(section: Table, key: str, default_port: Any) -> tuple[tuple[str, int], ...]:
    """``hosts = ["host[:port]", ...]`` as (host, port) pairs; a missing port is ``port``."""
    value = section.raw(key, [])
    if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
        raise section.fail(key, f'expected a list of "host[:port]" strings, got {value!r}')
    found = []
    for item in value:
        host, colon, port = item.strip().rpartition(":")
        if not colon:
            host, port = item.strip(), str(default_port)
        if not host or any(ch.isspace() or ch in "/[]" for ch in host):
            raise section.fail(key, f"{item!r} is not host or host:port")
        if not port.isdigit() or not 1 <= int(port) <= 65535:
            raise section.fail(key, f"{item!r}: the port must be a number in 1..65535")
        found.append((host, int(port)))
    return tuple(found)


def _folder(cwd: Path, text: str) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else (cwd / path).absolute()


_ENTRIES = Texts(empty_items=False)  # a list of strings, none of them blank


def _ident(section: Table, key: str, default: str) -> str:
    """A name that may stand in an MQTT topic: no spaces, ``/``, ``#`` or ``+``."""
    value = section.get(key, Text(empty=False), default)
    if any(ch in value for ch in "/#+ \t\n") or not value.isprintable():
        raise section.fail(key, f"{value!r} may not contain spaces, '/', '#' or '+'")
    return value


def _link(section: Table, key: str) -> StreamerConfig | None:
    """The printer link's table (``[printer.link]``), checked by the link's settings;
    None when it is not given."""
    value = section.raw(key, None)
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise section.fail(key, "expected a [table]")
    from drivers.link.config import StreamerConfig

    try:
        return StreamerConfig.from_mapping(value)
    except SettingError as exc:
        raise exc.within(section.key(key)) from exc


def _bed(section: Table, key: str,
         default: tuple[float, float, float]) -> tuple[float, float, float]:
    """The build volume ``[x, y, z]`` in mm, each 1..10000."""
    value = section.raw(key, list(default))
    if not isinstance(value, list) or len(value) != 3:
        raise section.fail(key, f"expected [x, y, z] in mm, got {value!r}")
    out = []
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float):
            raise section.fail(key, f"expected numbers, got {item!r}")
        if not math.isfinite(item) or not 1.0 <= item <= 10_000.0:
            raise section.fail(key, f"{item!r} is outside 1..10000 mm")
        out.append(float(item))
    return (out[0], out[1], out[2])
