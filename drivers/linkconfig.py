"""Link settings, states, counters and errors shared by the streamer and its callers."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.linkevents import LinkState

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


class LinkError(ConnectionError):
    """The link to the printer failed: port lost, printer silent, halted or emergency stop."""


class StreamCancelled(Exception):
    """The stream was cancelled: ``send()`` no longer accepts job lines."""


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
    """

    rx_buffer: int = 127
    bufsize: int = 4
    learn_bufsize: bool = True
    history: int = 10_000
    start_timeout_s: float = 2.0
    connect_timeout_s: float = 10.0
    probe_after_s: float = 5.0
    probe_retries: int = 3
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

    def __post_init__(self) -> None:
        if self.rx_buffer < 16:
            raise ValueError("rx_buffer must be at least 16 bytes")
        if self.bufsize < 1:
            raise ValueError("bufsize must be at least 1")
        if self.history < 64:
            raise ValueError("history must keep at least 64 lines")
        if self.probe_after_s <= 0 or self.start_timeout_s < 0:
            raise ValueError("timeouts must be positive")
        if self.renumber_at < 1000:
            raise ValueError("renumber_at must be at least 1000")


@dataclass
class StreamStats:
    """Counters of what the link has done (for logs and tests)."""

    lines_sent: int = 0
    bytes_sent: int = 0
    resends: int = 0
    lines_resent: int = 0
    duplicate_resends: int = 0
    implausible_resends: int = 0
    unconfirmed_resends: int = 0
    errors: int = 0
    probes: int = 0
    renumbers: int = 0
    resets: int = 0
    reconnects: int = 0
