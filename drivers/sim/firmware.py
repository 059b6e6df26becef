"""Marlin's main loop as the simulated printer runs it: receive buffer, line checks, queue.

The I/O thread plays the UART interrupt (``receive``); the firmware thread (``run``) reads
lines from the receive buffer into a command queue of ``bufsize`` commands, checking line
numbers and checksums exactly as Marlin's ``queue.cpp`` does, and executes one command at
a time, answering ``ok`` once it has been executed (for a move: once it is planned).
"""

from __future__ import annotations

import re
import threading
import time
from collections import Counter, defaultdict, deque
from collections.abc import Callable

from drivers.sim import commands as simcommands
from drivers.sim.clock import SimClock
from drivers.sim.config import SimulatorConfig
from drivers.sim.faults import FaultInjector
from drivers.sim.heater import BED, HOTEND, Heater, format_temperatures
from drivers.sim.lines import (
    RESEND_OK,
    check_line,
    m110_value,
    silently_dropped,
    spurious_replies,
)
from drivers.sim.motion import Motion
from drivers.sim.planner import MarlinPlanner, Move, move_block

ERR_KILLED = "Error:Printer halted. kill() called!"
BUSY = "echo:busy: processing"

_TERMINATOR = re.compile(rb"[\r\n]")
_EMERGENCY = re.compile(r"^\s*(?:N\d+\s*)?(M108|M112|M410)(?!\d)")


class Abort(Exception):
    """A reset, a kill or the end of the simulation cut the current command short."""


class Firmware:
    """The simulated Marlin: parser, command queue, executor and machine state."""

    def __init__(
        self,
        config: SimulatorConfig,
        send: Callable[[bytes], None],
        wait_sent: Callable[[float], bool],
        vanish: Callable[[], None],
        executed: Callable[[str], None],
    ) -> None:
        self.config = config
        self._send = send
        self._wait_sent = wait_sent
        self._vanish = vanish
        self._executed = executed
        self.faults = FaultInjector(config)
        self.clock = SimClock(config.time_scale)
        self.hotend = Heater(HOTEND, config.ambient_c)
        self.bed = Heater(BED, config.ambient_c)
        self.motion = Motion()
        self.planner = MarlinPlanner(config.planner())
        self.keepalive_s = config.keepalive_s
        self.autoreport_s = 0.0
        self.autoreport_changed = threading.Event()
        self.last_n = config.previous_lines  # an earlier host's, until a reset
        self.stats: Counter[str] = Counter()
        # simulated seconds by kind: motion, dwell, home
        self.times: defaultdict[str, float] = defaultdict(float)
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._rx = bytearray()
        self._partial = bytearray()
        self._eline = bytearray()
        self._queue: deque[tuple[str, int | None]] = deque()  # command, its line number
        self._no_ok: set[int | None] = set()  # lines whose own ok a refusal replaced
        self._interrupt = threading.Event()
        self._stopping = False
        self._reset_pending = False
        self._unplug_pending = False
        self._kill_pending = False
        self._halted = False
        self._cancel_wait = False
        self._quickstop = False
        self._booting_until = 0.0
        self._busy_next = 0.0

    # --- called from the I/O thread (the UART interrupt) -----------------------------

    def receive(self, data: bytes) -> None:
        """Bytes from the wire: into the receive buffer, bytes past its size are lost."""
        if self.config.emergency_parser:
            self._emergency_scan(data)
        with self._cond:
            if self._halted or time.monotonic() < self._booting_until:
                self.stats["rx_lost_bytes"] += len(data)
                return
            room = self.config.rx_buffer - len(self._rx)
            if len(data) > room:
                self.stats["rx_overflow_bytes"] += len(data) - max(0, room)
                data = data[: max(0, room)]
            self._rx += data
            self._cond.notify()

    def port_opened(self) -> None:
        """The host opened the port: an 8-bit board resets (DTR) unless configured not to."""
        if self.config.reset_on_open:
            self.request_reset()

    def request_reset(self) -> None:
        """Reset the printer as soon as the firmware thread can (thread-safe)."""
        with self._cond:
            self._reset_pending = True
            self._cond.notify()
        self._interrupt.set()

    def request_unplug(self) -> None:
        """Pull the cable now (thread-safe): a command waiting is cut short; see ``_unplug``."""
        with self._cond:
            self._unplug_pending = True
            self._cond.notify()
        self._interrupt.set()

    def stop(self) -> None:
        """Make ``run`` return (thread-safe)."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        self._interrupt.set()

    def _emergency_scan(self, data: bytes) -> None:
        if self._halted:
            return
        self._eline += data
        *lines, tail = _TERMINATOR.split(bytes(self._eline))
        self._eline = bytearray(tail[-self.config.max_cmd_size :])
        for raw in lines:
            if b"M1" not in raw and b"M4" not in raw:
                continue
            match = _EMERGENCY.match(raw.decode("latin-1"))
            if not match:
                continue
            code = match.group(1)
            with self._cond:
                if code == "M112":
                    self._kill_pending = True
                elif code == "M108":
                    self._cancel_wait = True
                else:
                    self._quickstop = True
                self._cond.notify()
            self._interrupt.set()

    # --- the firmware thread --------------------------------------------------------

    def run(self) -> None:
        """The main loop: until ``stop``."""
        idle_wait = self.config.no_timeouts_s or None
        while True:
            with self._cond:
                while not (
                    self._stopping or self._reset_pending or self._kill_pending
                    or self._unplug_pending or (not self._halted and (self._rx or self._queue))
                ):
                    if not self._cond.wait(idle_wait) and not self._halted:
                        self.emit("wait")  # NO_TIMEOUTS: idle, nothing received
                if self._stopping:
                    return
            try:
                if self._reset_pending:
                    self._reset()
                elif self._unplug_pending:
                    self._unplug()
                elif self._kill_pending:
                    self.kill("M112")
                else:
                    self._fill_queue()
                    if self._queue:
                        self._execute_next()
            except Abort:
                continue

    def _fill_queue(self) -> None:
        """Marlin's ``get_serial_commands``: read lines while the queue has room."""
        limit = self.config.max_cmd_size - 1
        while len(self._queue) < self.config.bufsize:
            with self._lock:
                if not self._rx:
                    return
                found = _TERMINATOR.search(self._rx)
                end = found.start() if found else len(self._rx)
                room = max(0, limit - len(self._partial))
                self._partial += self._rx[: min(end, room)]
                del self._rx[: end + 1 if found else end]
            if not found:
                return
            line = bytes(self._partial)
            self._partial.clear()
            if line:
                self._process_line(line)

    def _process_line(self, raw: bytes) -> None:
        """Marlin's ``process_line``: check the line, then queue its command."""
        self.stats["lines"] += 1
        if self.faults.fires("corrupt_rx"):
            raw = self.faults.flip_bit("corrupt_rx", raw)
        check = check_line(raw, self.last_n, self.config.m110_by_line)
        if check.error:
            if self.config.drop_duplicates and silently_dropped(check, self.last_n):
                self.stats["duplicates_dropped"] += 1
                return
            self._line_error(check.error)
            return
        self.last_n = check.last_n
        if not check.command:
            return
        self._queue.append((check.command, check.number))
        replies, withheld = spurious_replies(
            self.faults.fires, check.command, check.number, self.last_n
        )
        if withheld:
            self._no_ok.add(check.number)
        for reply in replies:
            if reply != RESEND_OK:
                self.emit(reply)
            elif self.config.ok_after_resend:
                self.send_ok()

    def _line_error(self, message: str) -> None:
        """Marlin's ``gcode_line_error``: report, drain the receive buffer, ask for a resend."""
        self.stats["errors"] += 1
        self.stats[message.split(",")[0]] += 1
        self.emit(f"Error:{message}{self.last_n}")
        if self.config.discard_after_error:
            with self._lock:
                self._rx.clear()
                self._partial.clear()
        self.emit(f"Resend: {self.last_n + 1}")
        if self.config.ok_after_resend:
            self.send_ok()

    def _execute_next(self) -> None:
        if self.faults.fires("reset"):
            self._wait_sent(2.0)
            self._reset()
            return
        if self._unplug_pending or self.faults.fires("disconnect"):
            self._unplug()
            return
        command, number = self._queue[0]
        if self._quickstop:  # M410 from the emergency parser while between commands
            self._quickstop = False
            self.planner.clear()
        self._cancel_wait = False  # M108 only ends a wait already under way, as in Marlin
        self._busy_next = self.clock.now() + self.keepalive_s
        if self.faults.fires("busy"):
            for _ in range(self.faults.randint("busy", 1, 5)):
                self.emit(BUSY)
                self.wait_sim(self.keepalive_s, keepalive=False)
        if self.config.m110_twice and "M110" in command:
            with self._lock:  # taken when received, and again now that it runs
                self.last_n = number if self.config.m110_by_line and number is not None \
                    else m110_value(command, self.last_n)
        if simcommands.execute(self, command) and number not in self._no_ok:
            self.send_ok(line=number)  # the command still holds its queue slot, as in Marlin
        self._no_ok.discard(number)
        self._queue.popleft()

    # --- services for the command handlers ------------------------------------------

    def emit(self, line: str) -> None:
        """Send one line to the host (subject to the printer -> host corruption fault)."""
        data = (line + "\n").encode("latin-1", "replace")
        if self.faults.fires("corrupt_tx"):
            data = self.faults.flip_bit("corrupt_tx", data)
        self._send(data)

    def send_ok(self, suffix: str = "", line: int | None = None) -> None:
        """Send ``ok``, or with ADVANCED_OK ``ok N<line> P<planner free> B<queue free>``.

        ``N`` is the executed command's own line number and is left out for unnumbered
        commands and for the ``ok`` after a resend request. ``suffix`` replaces the
        advanced fields (M105's temperatures). The drop-ok fault may swallow the line.
        """
        if self.faults.fires("drop_ok"):
            return
        if suffix:
            self.emit("ok" + suffix)
        elif self.config.advanced_ok:
            free_q = self.config.bufsize - len(self._queue)
            free_p = self.planner.free(self.clock.now())
            number = "" if line is None else f" N{line}"
            self.emit(f"ok{number} P{free_p} B{free_q}")
        else:
            self.emit("ok")

    def log_executed(self, command: str) -> None:
        """Record one executed command."""
        self.stats["executed"] += 1
        self._executed(command)

    def temperatures(self) -> str:
        """The heater report as M105 and auto-report print it (leading blank)."""
        with self._lock:
            return format_temperatures(self.hotend, self.bed, self.clock.now())

    def set_target(self, heater: Heater, target_c: float) -> None:
        """Set a heater's target at the current simulated time."""
        with self._lock:
            heater.set_target(target_c, self.clock.now())

    def set_autoreport(self, seconds: float) -> None:
        """M155 S<s>: temperature reports every ``s`` wall seconds (0 = off)."""
        self.autoreport_s = max(0.0, seconds)
        self.autoreport_changed.set()

    def wait_sim(self, seconds: float, cancellable: bool = False, keepalive: bool = True) -> bool:
        """Let ``seconds`` of simulated time pass, sending ``busy`` every keepalive interval.

        Returns False if cut short by M108 (only when ``cancellable``); raises ``Abort`` on a
        reset, a kill or the end of the simulation.
        """
        end = self.clock.now() + seconds
        while True:
            self._interrupt.clear()
            self._check_interrupts()
            if cancellable and self._cancel_wait:
                self._cancel_wait = False
                return False
            now = self.clock.now()
            if keepalive and now >= self._busy_next - 1e-9:
                self.emit(BUSY)
                self._busy_next = now + self.keepalive_s
            if now >= end - 1e-9:
                return True
            step = end - now
            if keepalive:
                step = min(step, self._busy_next - now)
            self.clock.wait(step, self._interrupt)

    def plan_move(self, delta: Move, speed: float) -> None:
        """Add a move (X, Y, Z, E mm at ``speed`` mm/s) to the planner, waiting while it is
        full (no planner: the move runs now, from rest to rest)."""
        planned = move_block(delta, speed, self.planner.settings, self.planner.previous)
        if planned is None:
            return
        block, self.planner.previous = planned
        if self.config.planner_blocks == 0:
            self.planner.previous = None
            self.wait_sim(block.length / block.speed)
            return
        now = self.clock.now()
        free_at = self.planner.next_free_at(now)
        if free_at > now:
            self.wait_sim(free_at - now)
        self.planner.add_block(self.clock.now(), block)

    def buffer_report(self) -> str:
        """Marlin's buffer monitoring line (``M576 P.. B.. PU.. PD.. BU.. BD..``)."""
        report = self.planner.report(self.clock.now())
        return report.line(self.config.bufsize - len(self._queue))

    def synchronize(self) -> None:
        """Marlin's ``planner.synchronize()``: wait until every block has been executed."""
        now = self.clock.now()
        idle = self.planner.idle_at(now)
        if idle > now:
            self.wait_sim(idle - now)

    def kill(self, command: str | None = None) -> None:
        """M112: report, switch everything off and halt until a reset."""
        if command:
            self.log_executed(command)
        self.emit(ERR_KILLED)
        with self._cond:
            self._kill_pending = False
            self._halted = True
            self._rx.clear()
            self._partial.clear()
            self._queue.clear()
        self._power_off()
        raise Abort

    def _unplug(self) -> None:
        """The cable is pulled between two commands, once every reply already produced is out.

        A USB-powered board (``reset_on_open``) loses power with it: queue, receive buffer
        and line numbers are gone; it boots when the host opens the port again.
        """
        self._unplug_pending = False
        self._wait_sent(2.0)
        self._vanish()
        if self.config.reset_on_open:
            self._reset(power_cycle=False)

    def _check_interrupts(self) -> None:
        if self._stopping or self._reset_pending or self._unplug_pending:
            raise Abort  # a wait under way is cut short: the command never completes
        if self._kill_pending:
            self.kill("M112")
        if self._quickstop:
            self._quickstop = False
            self.planner.clear()

    def _power_off(self) -> None:
        with self._lock:
            now = self.clock.now()
            self.hotend.reset(now)
            self.bed.reset(now)
        self.planner.clear()
        self.set_autoreport(0.0)

    def _reset(self, power_cycle: bool = True) -> None:
        """A hardware reset: everything volatile lost, then (after booting) the banner.

        Without ``power_cycle`` the board just stops (power lost): no boot, no banner.
        """
        if power_cycle:
            self.stats["resets"] += 1
        boot = self.config.boot_delay_s if power_cycle else 0.0
        with self._cond:
            self._reset_pending = False
            self._kill_pending = False
            self._halted = False
            self._cancel_wait = False
            self._quickstop = False
            self._booting_until = time.monotonic() + boot
            self._rx.clear()
            self._partial.clear()
            self._queue.clear()
            self._no_ok.clear()
            self.last_n = 0
        self._power_off()
        self.motion.reset()
        self.keepalive_s = self.config.keepalive_s
        if not power_cycle:
            return
        if boot > 0.0:
            self._interrupt.clear()
            self._interrupt.wait(boot)
            if self._stopping:
                raise Abort
        if self.config.banner:
            for line in simcommands.banner():
                self.emit(line)
