"""Link settings, states and counters shared by the streamer and its callers."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from drivers.link.events import LinkState
from slicer.options import Flag, Number, SettingError, Texts, Whole

LONG_COMMANDS = frozenset(
    {"M109", "M190", "M191", "G28", "G29", "G30", "G32", "G34", "M400", "G4", "M600", "M303",
     "M226", "M0", "M1"}
)

# link states (members of LinkState, equal to their names in lower case)
DISCONNECTED = LinkState.DISCONNECTED
CONNECTING = LinkState.CONNECTING
RECONNECTING = LinkState.RECONNECTING
READY = LinkState.READY
PAUSED = LinkState.PAUSED
CANCELLED = LinkState.CANCELLED
ERROR = LinkState.ERROR
HALTED = LinkState.HALTED


@dataclass(frozen=True)
class StreamerConfig:
    """How the streamer drives the printer. Times in seconds, sizes in bytes.

    - ``rx_buffer``: most unacknowledged bytes on the wire and in the firmware's receive
      buffer (Marlin: 128-byte ring, so 127).
    - ``bufsize``: most unacknowledged commands (Marlin ``BUFSIZE``); raised to what the
      advanced ``ok ... B<n>`` reports when ``learn_bufsize``.
    - ``history``: lines kept for resends (far more than a window).
    - ``start_timeout_s``: after opening, how long to wait for ``start`` (board reset).
    - ``probe_after_s``: silence, with lines in flight, before an ``M105`` probe.
    - ``probe_retries``: unanswered probes before the link is declared dead.
    - ``busy_silence_s``: silence after which a printer is taken as not blocked in a
      command (Marlin says ``busy:`` every 2 s while one blocks), so that a probe may go
      into a receive buffer the window says full (then one more each time it doubles).
    - ``long_command_timeout_s``: silence tolerated while a long command (``M109``,
      ``G28``...) is in flight; busy and temperature lines reset the silence.
    - ``temperature_interval_s``: ``M155 S<n>`` auto-report when offered, else ``M105`` polls
      at this interval; 0 turns both off.
    - ``renumber_at``: line number beyond which ``M110 N0`` restarts numbering (drained first).
    - ``park_gcode`` / ``unpark_gcode``: sent by ``pause()`` / ``resume()``.
    - ``resync_quiet_s``: after a reset, silence awaited before ``M110`` restores the line
      number, so that refusals of lines sent before the reset are not taken for its own.
    - ``renumber_retry_s``: silence after an ``M110`` before it is written again.
    - ``ok_after_resend``: the firmware answers ``Error`` + ``Resend`` with an ``ok`` (Marlin
      2.1); set False for builds that send none. A wrong guess costs time, not lines.
    - ``reconnect_attempts`` / ``reconnect_delay_s``: after the port is lost.
    - ``firmware_defaults``: at connect, the firmware's name and ``M115`` capabilities
      choose defaults for the settings not in ``explicit`` (:mod:`drivers.link.profile`).
    - ``read_motion``: at connect, ``M503`` asks the printer for its motion settings
      (accelerations, maximum feedrates, junction deviation: :mod:`drivers.link.motion`).
    - ``explicit``: settings the user chose (``[printer.link]``); never overridden.
    """

    rx_buffer: int = 127
    bufsize: int = 4
    learn_bufsize: bool = True
    history: int = 10_000
    start_timeout_s: float = 2.0
    connect_timeout_s: float = 10.0
    probe_after_s: float = 5.0
    probe_retries: int = 3
    busy_silence_s: float = 4.0
    long_command_timeout_s: float = 900.0
    temperature_interval_s: float = 2.0
    renumber_at: int = 100_000
    park_gcode: tuple[str, ...] = ()
    unpark_gcode: tuple[str, ...] = ()
    ok_after_resend: bool = True
    resync_quiet_s: float = 0.2
    renumber_retry_s: float = 1.0
    reconnect_attempts: int = 0
    reconnect_delay_s: float = 1.0
    firmware_defaults: bool = True
    read_motion: bool = True
    explicit: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        _check(16 <= self.rx_buffer <= 65536, "rx_buffer", "must be 16..65536 bytes")
        _check(1 <= self.bufsize <= 1024, "bufsize", "must be 1..1024 commands")
        _check(64 <= self.history <= 10_000_000, "history", "must keep 64..10000000 lines")
        _check(self.start_timeout_s >= 0, "start_timeout_s", "must be >= 0")
        for key in ("connect_timeout_s", "probe_after_s", "long_command_timeout_s",
                    "renumber_retry_s"):
            _check(getattr(self, key) > 0, key, "must be > 0")
        for key in ("temperature_interval_s", "resync_quiet_s", "reconnect_delay_s",
                    "busy_silence_s"):
            _check(getattr(self, key) >= 0, key, "must be >= 0")
        _check(self.probe_retries >= 1, "probe_retries", "must be >= 1")
        _check(self.reconnect_attempts >= 0, "reconnect_attempts", "must be >= 0")
        _check(self.renumber_at >= 1000, "renumber_at", "must be at least 1000")
        _check(self.renumber_at <= 2**31 - 1, "renumber_at", "must fit Marlin's long")
        unknown = self.explicit - set(self.setting_names())
        _check(not unknown, "explicit", f"names no setting: {sorted(unknown)}")

    @classmethod
    def setting_names(cls) -> tuple[str, ...]:
        """Names of the settings a user may set (``[printer.link]``)."""
        return tuple(f.name for f in fields(cls) if f.name != "explicit")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> StreamerConfig:
        """Settings from a mapping (a TOML table): every key checked, unknown keys refused.

        The keys given are recorded in ``explicit``: firmware defaults never override them.
        Raises :class:`~slicer.options.SettingError` naming the key.
        """
        defaults = cls()
        kwargs: dict[str, Any] = {}
        for key, value in values.items():
            if key not in cls.setting_names():
                raise SettingError(key, "unknown key")
            kwargs[key] = _typed(key, value, getattr(defaults, key))
        return cls(**kwargs, explicit=frozenset(kwargs))


# the one settings error (``slicer.options``), by the name the link has always used
LinkSettingError = SettingError


def _check(ok: bool, key: str, reason: str) -> None:
    if not ok:
        raise SettingError(key, reason)


def _typed(key: str, value: Any, default: Any) -> Any:
    """``value`` checked by the field of the setting's default's type (the ranges are
    checked by ``StreamerConfig`` itself, for settings made in code as well)."""
    if isinstance(default, bool):
        return Flag().check(key, value)
    if isinstance(default, int):
        return Whole().check(key, value)
    if isinstance(default, float):
        return Number().check(key, value)
    if isinstance(default, tuple):
        return Texts("G-code lines").check(key, value)
    return value


@dataclass
class StreamStats:
    """Counters of what the link has done (for logs and tests)."""

    lines_sent: int = 0
    bytes_sent: int = 0
    resends: int = 0
    lines_resent: int = 0
    duplicate_resends: int = 0
    replays_skipped: int = 0
    stand_ins_counted: int = 0  # oks after a Resend counted for the line it released
    implausible_resends: int = 0
    unconfirmed_resends: int = 0
    errors: int = 0
    probes: int = 0
    renumbers: int = 0
    resets: int = 0
    reconnects: int = 0
