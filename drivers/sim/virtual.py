"""The simulated Marlin on a virtual clock: the pty simulator's rules as discrete events.

Same line checks (:func:`drivers.sim.lines.check_line`), same seeded faults
(:class:`drivers.sim.faults.FaultInjector`, every kind but ``disconnect``), same receive buffer,
command queue, drain on error and message order as :mod:`drivers.sim.firmware`, but nothing
runs in real time: a :class:`VirtualWire` carries bytes both ways at ``baud / 10`` bytes per
second plus a one-way latency, and the caller advances one shared clock event by event. A
host (the protocol core, or anything else) talks to it through ``write`` and ``on_line``.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Callable

from drivers.sim.commands import FIRMWARE_NAME
from drivers.sim.config import SimulatorConfig
from drivers.sim.faults import FaultInjector
from drivers.sim.lines import (
    RESEND_OK,
    check_line,
    m110_value,
    silently_dropped,
    spurious_replies,
)

BUSY = "echo:busy: processing"
TEMPERATURES = " T:20.00 /0.00 B:20.00 /0.00 @:0 B@:0"


class Clock:
    """A virtual clock and its queue of timed callbacks (run in time order, then FIFO)."""

    def __init__(self) -> None:
        self.now = 0.0
        self._queue: list[tuple[float, int, Callable[..., None], tuple[object, ...]]] = []
        self._seq = itertools.count()
        self.stopped = False

    def at(self, when: float, action: Callable[..., None], *args: object) -> None:
        """Run ``action(*args)`` at virtual time ``when`` (not before now)."""
        now = self.now
        heapq.heappush(self._queue, (when if when > now else now, next(self._seq), action, args))

    def step(self) -> bool:
        """Run the next action; False when none is left."""
        if not self._queue:
            return False
        when, _, action, args = heapq.heappop(self._queue)
        self.now = when
        action(*args)
        return True

    def run(self, max_seconds: float) -> str:
        """Run actions in order until one calls :meth:`stop` (``""``), nothing is left
        (``"idle"``) or the clock passes ``max_seconds`` (``"late"``)."""
        queue = self._queue
        pop = heapq.heappop
        self.stopped = False
        while not self.stopped:
            if not queue:
                return "idle"
            when, _, action, args = pop(queue)
            self.now = when
            action(*args)
            if when > max_seconds:
                return "late"
        return ""

    def stop(self) -> None:
        """End :meth:`run` after the action running now."""
        self.stopped = True

    def next_time(self) -> float | None:
        """When the next action is due (``None``: nothing queued)."""
        return self._queue[0][0] if self._queue else None


class Lane:
    """One direction of the wire: bytes leave in order, each after its wire time.

    ``delay(size)`` may add an extra delay to one piece (order is kept: a piece never
    arrives before the one written before it).
    """

    def __init__(self, clock: Clock, rate: float, latency: float,
                 deliver: Callable[[bytes], None]) -> None:
        self.clock = clock
        self.rate = rate
        self.latency = latency
        self.deliver = deliver
        self.delay: Callable[[int], float] | None = None
        self._free_at = 0.0
        self._last_arrival = 0.0
        self.epoch = 0  # bumped when the wire is cut: pieces under way are lost

    def send(self, pieces: list[bytes]) -> None:
        """Put ``pieces`` (one write, maybe split) on the wire now."""
        epoch = self.epoch
        clock = self.clock
        rate = self.rate
        if len(pieces) == 1 and self.delay is None:
            piece = pieces[0]  # the usual case, without the per-piece bookkeeping
            now = clock.now
            free = (self._free_at if self._free_at > now else now) \
                + (len(piece) / rate if rate else 0.0)
            self._free_at = free
            arrival = free + self.latency
            if arrival < self._last_arrival:
                arrival = self._last_arrival
            self._last_arrival = arrival
            # Clock.at without the call (arrival is never before now)
            heapq.heappush(clock._queue, (arrival, next(clock._seq), self._arrive,
                                          (piece, epoch)))
            return
        for piece in pieces:
            start = self._free_at if self._free_at > clock.now else clock.now
            self._free_at = free = start + (len(piece) / rate if rate else 0.0)
            arrival = free + self.latency
            if self.delay is not None:
                arrival += self.delay(len(piece))
            if arrival < self._last_arrival:
                arrival = self._last_arrival
            self._last_arrival = arrival
            clock.at(arrival, self._arrive, piece, epoch)

    def _arrive(self, piece: bytes, epoch: int) -> None:
        if epoch == self.epoch:
            self.deliver(piece)


class VirtualPrinter:
    """Marlin's main loop as events: receive buffer, line checks, queue, one ok per command.

    ``write(data)`` puts host bytes on the wire; ``on_line(text)`` is called for every line
    the printer's replies deliver to the host. ``executed`` lists executed commands in
    order. ``split(data)`` may cut each host write into pieces (default: one piece).
    """

    def __init__(self, config: SimulatorConfig, clock: Clock,
                 on_line: Callable[[str], None], exec_s: float = 0.0) -> None:
        self.config = config
        self.clock = clock
        self.on_line = on_line
        self.exec_s = exec_s
        self.faults = FaultInjector(config, threaded=False)
        self._fires = self.faults.fires
        self._left = self.faults.left  # countdowns to each fault: counted here inline
        rate = config.bytes_per_second
        self.to_printer = Lane(clock, rate, config.latency_s, self._receive)
        self.to_host = Lane(clock, rate, config.latency_s, self._host_bytes)
        self.split: Callable[[bytes], list[bytes]] | None = None
        self.executed: list[str] = []
        # commands run without a line number: from a host that numbers every line, the
        # rest of a line whose first bytes were lost while the board booted after a reset
        self.unnumbered: list[str] = []
        self.last_n = config.previous_lines  # an earlier host's, until a reset
        self.errors = 0
        self.duplicates_dropped = 0
        self.resets = 0
        # bytes that arrived while the receive buffer was full (lost, as a UART loses them),
        # and how many arrivals lost some: a host that respects the buffer never makes any
        self.overrun_bytes = 0
        self.overruns = 0
        self._rx = bytearray()
        self._partial = bytearray()
        self._host_partial = bytearray()
        self._queue: deque[tuple[str, int | None]] = deque()
        self._no_ok: set[int | None] = set()  # lines whose own ok a refusal replaced
        self._running = False
        self._booting_until = 0.0
        self._boot_id = 0

    # -- the host's side -----------------------------------------------------------------

    def write(self, data: bytes) -> None:
        """Host bytes onto the wire, now."""
        self.to_printer.send(self.split(data) if self.split else [data])

    def power_on(self) -> None:
        """The port opens: the board boots (``start`` after the boot delay), or, without
        ``reset_on_open``, goes on counting an earlier host's lines."""
        if self.config.reset_on_open:
            self._reset()

    # -- the UART --------------------------------------------------------------------------

    def _receive(self, data: bytes) -> None:
        if self.clock.now < self._booting_until:
            return  # lost while booting
        room = self.config.rx_buffer - len(self._rx)
        if len(data) > room:
            self.overrun_bytes += len(data) - max(0, room)
            self.overruns += 1
            data = data[: max(0, room)]
        self._rx += data
        self._serve()

    def _host_bytes(self, data: bytes) -> None:
        if not self._host_partial and data.find(b"\n") == len(data) - 1:
            self.on_line(data[:-1].decode("ascii", "replace"))  # one whole line: the usual
            return
        self._host_partial += data
        while True:
            end = self._host_partial.find(b"\n")
            if end < 0:
                return
            raw = bytes(self._host_partial[:end])
            del self._host_partial[: end + 1]
            self.on_line(raw.decode("ascii", "replace"))

    def emit(self, line: str) -> None:
        """One reply line (subject to the printer -> host corruption fault)."""
        data = _ENCODED.get(line)
        if data is None:
            data = (line + "\n").encode("latin-1", "replace")
            if len(_ENCODED) < 256 and (line.startswith("ok") or line == BUSY):
                _ENCODED[line] = data  # the same few oks, line after line
        left = self._left
        if left["corrupt_tx"]:
            left["corrupt_tx"] -= 1
        elif self.faults.fire("corrupt_tx"):
            data = self.faults.flip_bit("corrupt_tx", data)
        self.to_host.send([data])

    # -- the main loop ---------------------------------------------------------------------

    def _serve(self) -> None:
        """Read lines into the queue while it has room; run the next command if idle."""
        limit = self.config.max_cmd_size - 1
        bufsize = self.config.bufsize
        rx = self._rx
        while len(self._queue) < bufsize and rx:
            end = rx.find(b"\n")
            if 0 < end <= limit and not self._partial:
                line = bytes(rx[:end])  # a whole line that fits: the usual case
                del rx[: end + 1]
                self._process_line(line)
                continue
            stop = end if end >= 0 else len(self._rx)
            room = max(0, limit - len(self._partial))
            self._partial += self._rx[: min(stop, room)]
            del self._rx[: end + 1 if end >= 0 else stop]
            if end < 0:
                break
            line = bytes(self._partial)
            self._partial.clear()
            if line:
                self._process_line(line)
        if not self._running and self._queue:
            self._start_next()

    def _process_line(self, raw: bytes) -> None:
        left = self._left
        if left["corrupt_rx"]:
            left["corrupt_rx"] -= 1
        elif self.faults.fire("corrupt_rx"):
            raw = self.faults.flip_bit("corrupt_rx", raw)
        config = self.config
        check = check_line(raw, self.last_n, config.m110_by_line)
        if check.error:
            if config.drop_duplicates and silently_dropped(check, self.last_n):
                self.duplicates_dropped += 1
                return
            self.errors += 1
            self.emit(f"Error:{check.error}{self.last_n}")
            if config.discard_after_error:
                self._rx.clear()
                self._partial.clear()
            self.emit(f"Resend: {self.last_n + 1}")
            if self.config.ok_after_resend:
                self._ok()
            return
        self.last_n = check.last_n
        if not check.command:
            return
        self._queue.append((check.command, check.number))
        left = self._left
        if left["resend"] and left["refuse"] and left["refuse_next"] \
                and check.number is not None:
            left["resend"] -= 1  # no noise fires after this line: the draws counted
            left["refuse"] -= 1
            left["refuse_next"] -= 1
            if "M110" in check.command:  # a renumbering draws nothing: take them back
                left["resend"] += 1
                left["refuse"] += 1
                left["refuse_next"] += 1
            return
        replies, withheld = spurious_replies(
            self._fires, check.command, check.number, self.last_n
        )
        if withheld:
            self._no_ok.add(check.number)
        for reply in replies:
            if reply != RESEND_OK:
                self.emit(reply)
            elif config.ok_after_resend:
                self._ok()

    def _start_next(self) -> None:
        left = self._left
        if left["reset"]:
            left["reset"] -= 1
        elif self.faults.fire("reset"):
            self._reset()
            return
        self._running = True
        delay = self.exec_s
        if left["busy"]:
            left["busy"] -= 1
        elif self.faults.fire("busy"):
            for k in range(self.faults.randint("busy", 1, 5)):
                self.clock.at(self.clock.now + k * self.config.keepalive_s, self.emit, BUSY)
                delay += self.config.keepalive_s
        boot = self._boot_id
        self.clock.at(self.clock.now + delay, self._finish, boot)

    def _finish(self, boot: int) -> None:
        if boot != self._boot_id:
            return  # a reset cut the command short
        command, number = self._queue.popleft()
        self._running = False
        if self.config.m110_twice and "M110" in command:
            # taken when received, and again now that it runs
            self.last_n = number if self.config.m110_by_line and number is not None \
                else m110_value(command, self.last_n)
        if self._no_ok and number in self._no_ok:
            self._no_ok.discard(number)
            self.executed.append(command)  # it runs; a refusal's ok stood for its own
            self._serve()
            return
        code = command.split(" ", 1)[0]
        known = _KNOWN.get(code)
        if known is None:
            known = _known(code)
        if known:
            self.executed.append(command)  # an unknown command runs as nothing, as in Marlin
            if number is None:
                self.unnumbered.append(command)
        if code == "M105":
            self._ok(TEMPERATURES)
        elif code == "M115":
            self.emit(f"FIRMWARE_NAME:{FIRMWARE_NAME} PROTOCOL_VERSION:1.0")
            self.emit(f"Cap:EMERGENCY_PARSER:{int(self.config.emergency_parser)}")
            self._ok()
        else:
            if not known:
                self.emit(f'echo:Unknown command: "{command}"')
            self._ok()
        self._serve()

    def _ok(self, suffix: str = "") -> None:
        left = self._left
        if left["drop_ok"]:
            left["drop_ok"] -= 1
        elif self.faults.fire("drop_ok"):
            return
        if suffix or not self.config.advanced_ok:
            self.emit("ok" + suffix)
        else:
            self.emit(f"ok P15 B{self.config.bufsize - len(self._queue)}")

    def _reset(self) -> None:
        """Everything volatile lost; ``start`` once booted (bytes meanwhile are lost)."""
        self.resets += 1
        self._boot_id += 1
        self._rx.clear()
        self._partial.clear()
        self._queue.clear()
        self._no_ok.clear()
        self._running = False
        self.last_n = 0
        self._booting_until = self.clock.now + self.config.boot_delay_s
        if self.config.banner:
            self.clock.at(self._booting_until, self.emit, "start")


def _known(code: str) -> bool:
    known = _KNOWN.get(code)
    if known is None:
        known = len(code) > 1 and code[0] in "GMT" and code[1:].isdigit()
        if len(_KNOWN) < 4096:
            _KNOWN[code] = known
    return known


_KNOWN: dict[str, bool] = {}  # command word -> whether it runs
_ENCODED: dict[str, bytes] = {}  # reply line -> its bytes on the wire
