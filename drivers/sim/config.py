"""Settings of the simulated Marlin printer: one frozen, range-checked dataclass."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from drivers.sim.planner import PlannerSettings
from slicer.options import SettingError

# names of the fault probabilities, in the order they are documented
FAULT_KINDS = (
    "corrupt_rx",
    "corrupt_tx",
    "drop_ok",
    "resend",
    "refuse",
    "refuse_next",
    "busy",
    "reset",
    "disconnect",
)


@dataclass(frozen=True)
class SimulatorConfig:
    """Everything that shapes the simulated printer; immutable once built.

    Times are in seconds. ``time_scale`` multiplies every *simulated* duration (moves,
    dwells, homing, heating, keepalive interval) to give wall time: 1.0 is real time,
    0.0 is instant. ``no_timeouts_s`` > 0 makes the idle printer print ``wait`` every that
    many wall seconds (Marlin's NO_TIMEOUTS). ``baud`` limits the wire in both directions
    to ``baud / 10`` bytes/s (8N1 framing); 0 means unlimited. Every byte is delivered
    only once its ten bits have crossed the wire, behind the bytes before it.
    ``latency_s`` is the link's one-way delay, added to every byte in each direction on
    top of its wire time: it stands for USB frames (about 1 ms; an FTDI adapter's latency
    timer defaults to 16 ms) and the firmware's main loop, so a command's round trip
    takes at least twice the latency plus the wire time of the line and its answer.
    The default 0.0 (an ideal link) keeps protocol tests fast; timing studies set it.

    Fault probabilities (0..1), drawn from one seeded generator per fault kind:

    - ``p_corrupt_rx``: per received line, one bit of one byte flipped (host -> printer);
    - ``p_corrupt_tx``: per sent line, one bit of one byte flipped (printer -> host);
    - ``p_drop_ok``: per ``ok``, the line is not sent;
    - ``p_resend``: per accepted numbered line, a spurious ``Resend: <that line>`` although
      the line was fine; it is executed once and answered by its one ``ok`` as usual, and a
      re-sent copy is rejected as a duplicate (line-number error);
    - ``p_refuse``: per accepted numbered line, a spurious refusal in Marlin's own form,
      ``Error:checksum mismatch, Last Line: <that line>``, ``Resend: <the next>`` and (with
      ``ok_after_resend``) ``ok``, as noise on a real board's replies produces; nothing is
      drained, so the lines behind it on the wire are accepted as usual;
    - ``p_refuse_next``: per accepted numbered line, the refusal an emulation makes of the
      *next* line, before it was sent: ``Error:checksum mismatch, Last Line: <that line>``,
      ``Resend: <the next>`` and (with ``ok_after_resend``) ``ok``, which is the only ok
      the line gets (it still runs, but its own ``ok`` never comes);
    - ``p_busy``: per executed command, a burst of 1-5 ``echo:busy: processing`` lines,
      each after one keepalive interval of simulated time;
    - ``p_reset``: per executed command, a reset before it (queue, receive buffer,
      line numbers, heaters and position lost; ``start`` printed after the boot delay);
    - ``p_disconnect``: per executed command, the pseudo-terminal is closed before it (the
      port vanishes); with ``reset_on_open`` (a USB-powered board) the printer loses power
      with it. With ``link_path`` the printer comes back on a new pseudo-terminal after
      ``reconnect_delay_s`` and the symlink is pointed at it; without, it never comes back.

    Resets and disconnects happen between commands, after every reply already produced
    has been written, so an ``ok`` never goes missing with them: every acknowledged line
    was executed and no other line was. (A *dropped* ``ok`` just before a reset is the one
    case no host can resolve; combine those two kinds knowingly.)

    Other settings: ``rx_buffer`` bytes of receive buffer, ``bufsize`` queued commands,
    ``planner_blocks`` (0 = no planner: a move's ``ok`` waits for the move),
    ``acceleration`` mm/s² (``M204 P R T`` and the ``M201`` X and Y maxima, reported by
    ``M503``), ``max_cmd_size`` bytes per line, ``emergency_parser`` (M108/M112/M410 acted on as the
    bytes arrive), ``ok_after_resend`` (False: Marlin 2.0 builds that answer an error with
    ``Resend`` only), ``reset_on_open`` (opening the port resets the board, as DTR does),
    ``boot_delay_s`` (wall time from reset to ``start``; bytes meanwhile are lost),
    ``drop_duplicates`` (a line numbered as the last one received, or one below it, is
    dropped silently: no ``ok``, no error), ``discard_after_error`` (False: the receive
    buffer is kept after a refused line, and each line in it is checked in turn),
    ``m110_by_line`` (``N<k> M110 N<m>`` sets the last line to the line's own ``k``, not
    to the parameter ``m``), ``m110_twice`` (``M110`` takes effect when received and again
    when run: a line taken between the two is refused), ``banner`` (False: no ``start``
    after a reset), ``previous_lines`` (the last line number an earlier host left, kept
    when the port opens without a reset, ``reset_on_open`` False),
    ``log_path`` (executed commands, one a line), ``keep_executed`` (False: the executed
    commands are not kept in ``SimulatedPrinter.executed``, a list that grows by every
    line printed; a long-running host reads them from ``log_path`` instead),
    ``link_path`` (a symlink kept pointing at the current pseudo-terminal), ``seed`` (of
    every fault generator).
    """

    time_scale: float = 1.0
    baud: int = 250000
    latency_s: float = 0.0
    rx_buffer: int = 128
    bufsize: int = 4
    planner_blocks: int = 16
    acceleration: float = 3000.0
    max_cmd_size: int = 96
    advanced_ok: bool = False
    emergency_parser: bool = True
    ok_after_resend: bool = True
    reset_on_open: bool = True
    drop_duplicates: bool = False
    discard_after_error: bool = True
    m110_by_line: bool = False
    m110_twice: bool = False
    banner: bool = True
    previous_lines: int = 0
    boot_delay_s: float = 0.05
    keepalive_s: float = 2.0
    no_timeouts_s: float = 0.0
    ambient_c: float = 20.0
    log_path: str | None = None
    keep_executed: bool = True
    link_path: str | None = None
    reconnect_delay_s: float = 0.2
    seed: int = 0
    p_corrupt_rx: float = 0.0
    p_corrupt_tx: float = 0.0
    p_drop_ok: float = 0.0
    p_resend: float = 0.0
    p_refuse: float = 0.0
    p_refuse_next: float = 0.0
    p_busy: float = 0.0
    p_reset: float = 0.0
    p_disconnect: float = 0.0

    def __post_init__(self) -> None:
        _check(self.time_scale >= 0.0, "time_scale", "must be >= 0")
        _check(self.baud >= 0, "baud", "must be >= 0 (0 = unlimited)")
        _check(0.0 <= self.latency_s <= 1.0, "latency_s", "must be in 0..1 second")
        _check(self.rx_buffer >= 1, "rx_buffer", "must be >= 1 byte")
        _check(self.bufsize >= 1, "bufsize", "must be >= 1 command")
        _check(self.planner_blocks >= 0, "planner_blocks", "must be >= 0 (0 = no planner)")
        _check(10.0 <= self.acceleration <= 100_000.0, "acceleration",
               "must be 10..100000 mm/s²")
        _check(self.max_cmd_size >= 8, "max_cmd_size", "must be >= 8 bytes")
        _check(self.boot_delay_s >= 0.0, "boot_delay_s", "must be >= 0")
        _check(self.keepalive_s > 0.0, "keepalive_s", "must be > 0")
        _check(self.no_timeouts_s >= 0.0, "no_timeouts_s", "must be >= 0 (0 = never 'wait')")
        _check(self.previous_lines >= 0, "previous_lines", "must be >= 0")
        _check(self.reconnect_delay_s >= 0.0, "reconnect_delay_s", "must be >= 0")
        for kind in FAULT_KINDS:
            p = getattr(self, f"p_{kind}")
            _check(0.0 <= p <= 1.0, f"p_{kind}", "must be a probability in 0..1")

    @property
    def bytes_per_second(self) -> float:
        """Wire speed in bytes/s (8N1: ten bits a byte); 0.0 for an unlimited wire."""
        return self.baud / 10.0

    def planner(self) -> PlannerSettings:
        """The settings of the simulated printer's planner: Marlin's defaults with
        ``planner_blocks`` and ``acceleration`` (printing, travel, retracts, X and Y)."""
        base = PlannerSettings()
        a = self.acceleration
        return replace(base, blocks=max(1, self.planner_blocks), acceleration=a,
                       travel_acceleration=a, retract_acceleration=a,
                       max_acceleration=(a, a, base.max_acceleration[2],
                                         base.max_acceleration[3]))

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """Names of every setting, for callers that build a config from a mapping."""
        return tuple(f.name for f in fields(cls))


# Firmware dialects: the settings that make each, and the seeded fault kind that shows it
# (a host that mishandles the dialect stalls or loses a line under that fault)
DIALECTS: dict[str, tuple[dict[str, object], str]] = {
    "marlin": ({}, "refuse"),
    "next_line": ({}, "refuse_next"),
    "silent_duplicates": ({"drop_duplicates": True}, "refuse"),
    "keep_buffer": ({"discard_after_error": False}, "corrupt_rx"),
    "m110_by_line": ({"m110_by_line": True}, "reset"),
    "m110_twice": ({"m110_twice": True}, "reset"),
    "no_banner": ({"banner": False}, "corrupt_tx"),
    "no_reset_on_open": ({"reset_on_open": False, "previous_lines": 137}, "refuse"),
}


def dialect(name: str, p: float = 0.0, **settings: object) -> SimulatorConfig:
    """A printer of dialect ``name`` (:data:`DIALECTS`) with its fault at probability ``p``
    and any other ``settings``."""
    overrides, fault = DIALECTS[name]
    merged: dict[str, object] = {**overrides, **settings}
    if p:
        merged[f"p_{fault}"] = p
    return SimulatorConfig(**merged)  # type: ignore[arg-type]


def _check(ok: bool, key: str, reason: str) -> None:
    """Raise the project's one settings error (:class:`~slicer.options.SettingError`,
    a ``ValueError``) naming ``key`` unless ``ok``."""
    if not ok:
        raise SettingError(key, reason)
