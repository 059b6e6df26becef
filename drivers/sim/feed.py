"""A whole print fed to the planner through a serial wire model, judged on a virtual clock.

The host sends numbered lines over a wire of ``baud`` (8N1: ten bits a byte),
either ahead of the printer within a window (``window_lines`` commands and
``window_bytes`` bytes not yet acknowledged, as the project's streamer and
Marlin's 128-byte receive buffer and 4-command queue allow) or one line at a
time, waiting for each ``ok`` (a send-and-wait host). The printer executes
commands in order: a move is done once its blocks are in the planner
(:class:`drivers.sim.planner.MarlinPlanner`), an arc is cut into chords first,
and ``ok`` goes back over the wire. Dwells, homing and heater waits
synchronize the planner (their own durations are left out: the figures are
about motion). A print of hours is judged in seconds of computing.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from drivers.link.protocol import strip_comment
from drivers.sim.commands import parse
from drivers.sim.motion import Motion, MotionLimits
from drivers.sim.planner import MarlinPlanner, Move, PlannerSettings, move_block

# commands that wait for the planner to empty before they run
_SYNC = frozenset({"G4", "G28", "G29", "M109", "M190", "M400"})
# "ok\n" back to the host, bytes
_OK_BYTES = 3


@dataclass(frozen=True)
class FeedResult:
    """What a print fed over a wire did: lines and framed bytes sent, the time the
    print took (s, virtual), the planner's underruns, starved time (s) and stalls (see
    ``drivers.sim.planner``), moves and arcs executed, and the blocks planned."""

    lines: int
    bytes: int
    print_s: float
    underruns: int
    starved_s: float
    stalls: int
    moves: int
    arcs: int
    blocks: int

    @property
    def lines_per_s(self) -> float:
        """Mean line rate over the print."""
        return self.lines / self.print_s if self.print_s > 0 else 0.0


def framed_bytes(number: int, command: str) -> int:
    """Bytes of ``N<number> <command>*<cs>\\n`` on the wire, counting three checksum digits."""
    return len(command) + len(str(number)) + 6


def simulate_feed(
    lines: Iterable[str],
    baud: int,
    *,
    send_and_wait: bool = False,
    window_lines: int = 4,
    window_bytes: int = 127,
    latency_s: float = 0.001,
    settings: PlannerSettings | None = None,
    acks: list[float] | None = None,
) -> FeedResult:
    """Feed G-code ``lines`` (comments and blanks are not sent) through a wire of ``baud``
    to a simulated Marlin; see the module docstring. ``latency_s`` is added one way to
    every line and every ``ok``; ``baud`` 0 is a wire without limit (the well-fed print).
    When given, ``acks`` (an empty list) receives the time (s) each line's ``ok`` reached the host.
    Raises ValueError for a baud rate from 1 to 1199.
    """
    if 0 < baud < 1200 or baud < 0:
        raise ValueError(f"baud {baud}: too slow for a printer link")
    settings = settings or PlannerSettings()
    byte_s = 10.0 / baud if baud else 0.0
    ok_s = _OK_BYTES * byte_s + latency_s
    width = 1 if send_and_wait else max(1, window_lines)
    planner = MarlinPlanner(settings)
    motion = Motion(MotionLimits())
    sizes: list[int] = []  # framed bytes of each line sent
    ok_at: list[float] = [] if acks is None else acks  # when each line's ok reached the host
    low = 0  # first line whose bytes still count against the window
    in_window = 0  # bytes of lines low..current-1
    wire_free = 0.0
    done = 0.0  # when the printer finished the previous command
    moves = arcs = 0
    for raw in lines:
        command = strip_comment(raw)
        if not command:
            continue
        i = len(sizes)
        size = framed_bytes(i + 1, command)
        # the window: at most `width` lines and `window_bytes` bytes unacknowledged
        first = max(low, i - width + 1)
        while low < first:
            in_window -= sizes[low]
            low += 1
        while low < i and in_window + size > window_bytes:
            in_window -= sizes[low]
            low += 1
        first = low
        opens = ok_at[first - 1] if first > 0 else 0.0
        start = max(wire_free, opens)
        wire_free = start + size * byte_s
        arrived = wire_free + latency_s
        t = max(arrived, done)
        parsed = parse(command)
        if parsed is not None:
            code, params = parsed
            values = {k: v for k, v in params.items() if v is not None}
            if code in ("G0", "G1"):
                delta, speed, duration = motion.move_delta(values)
                if duration > 0.0:
                    moves += 1
                    t = _plan(planner, t, delta, speed)
            elif code in ("G2", "G3"):
                try:
                    chords, _length, duration = motion.arc(values, code == "G2", settings)
                except ValueError:
                    chords, duration = [], 0.0
                if duration > 0.0:
                    moves += 1
                    arcs += 1
                    for delta, speed in chords:
                        t = _plan(planner, t, delta, speed)
            elif code in _SYNC:
                if code == "G28":
                    motion.home("".join(a for a in "XYZ" if a in params))
                t = planner.idle_at(t)
            else:
                _set_mode(motion, code, values)
        done = t
        sizes.append(size)
        in_window += size
        ok_at.append(done + ok_s)
    end = planner.idle_at(done)
    return FeedResult(
        lines=len(sizes),
        bytes=sum(sizes),
        print_s=end,
        underruns=planner.underruns,
        starved_s=planner.starved_s,
        stalls=planner.stalls,
        moves=moves,
        arcs=arcs,
        blocks=planner.blocks_done,
    )


def _plan(planner: MarlinPlanner, t: float, delta: Move, speed: float) -> float:
    """Queue one move's block at ``t`` or once a slot frees; returns when it was queued."""
    planned = move_block(delta, speed, planner.settings, planner.previous)
    if planned is None:
        return t
    block, planner.previous = planned
    return planner.add_block(t, block)


def ideal_print_s(lines: Iterable[str]) -> float:
    """Nominal motion time of ``lines`` (length / feedrate, no acceleration), s."""
    motion = Motion(MotionLimits())
    total = 0.0
    for raw in lines:
        parsed = parse(strip_comment(raw))
        if parsed is None:
            continue
        code, params = parsed
        values = {k: v for k, v in params.items() if v is not None}
        if code in ("G0", "G1"):
            total += motion.move_delta(values)[2]
        elif code in ("G2", "G3"):
            try:
                total += motion.arc(values, code == "G2", PlannerSettings())[2]
            except ValueError:
                continue
        else:
            _set_mode(motion, code, values)
    return total


def _set_mode(motion: Motion, code: str, values: dict[str, float]) -> None:
    """Apply a positioning command (G90, G91, M82, M83, G92); any other code is ignored."""
    if code in ("G90", "G91"):
        motion.set_absolute(code == "G90")
    elif code in ("M82", "M83"):
        motion.absolute_e = code == "M82"
    elif code == "G92":
        motion.set_position(values)
