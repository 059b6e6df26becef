"""Streaming throughput on the simulated printer: windowed streamer vs wire and one-at-a-time.

Run from the repository root::

    .venv/bin/python -m bench.stream_throughput [--lines 5000] [--bauds 115200 250000]
        [--latencies-ms 0 1 4] [--noisy-lines 20000] [--fault-lines 100000] [--skip-wire]
        [--repeat 1]

The simulated printer runs in its own process (``hostd simulate``) with its wire limited
to the baud rate and a one-way link latency (USB frames and the firmware's loop: 0 is an
ideal link, about 1 ms a USB-serial adapter, more an FTDI one with its latency timer), so
the host's CPU time measured here is the host's alone. For each speed and latency the
table gives lines per second of the windowed streamer and of a send-one, wait-for-ok host
on the same simulator, the wire's line rate (baud / 10 bytes per second over the mean
framed line length), the ratios, and the CPU while streaming: the host's share of a core
and its CPU time per line (all of the streaming process's threads; the simulator is not
in it), the simulated printer's CPU time per line (its process, every thread), which
tells a slower printer model from a slower host when rates move, and the send-and-wait
host's CPU time per line: one write, one read and two event-loop wake-ups per line, the
least any asyncio host spends, a yardstick of the machine (its load) taken in the same run.

The wire table also runs against another revision's link, for comparisons on the same
machine and load: unpack that revision (``git archive REV | tar -x -C DIR``) and run this
file by its path from DIR with ``PYTHONPATH=.`` (the simulated printer is DIR's too).

A second table streams to the virtual-clock Marlin (``drivers.sim.virtual``, the same rules
on simulated time: the figures do not depend on the machine's load) at 250000 baud with 1 ms
of latency, with 2, 5 and 10 % of lines spuriously refused in both forms (Marlin's
``Error``/``Resend`` refusal of a line it took, and a bare ``Resend`` for a line already
sent) and both ``ok`` dialects, against a send-and-wait host on the same firmware. A last
line gives the wall-clock rate at which the protocol core gets through the fault suite
(every fault kind at 1 %).

``--peer octoprint`` runs instead the rows against an emulation nobody here wrote:
OctoPrint's virtual printer (``bench/octoprint_peer.py``, in a virtual environment of its
own created under ``bench/.cache/``: AGPL, never a dependency of the package) on a
pseudo-terminal paced to 250000 baud, clean and at its resend ratios (``--resend-ratios``),
the link at its defaults against a send-and-wait host that handles requests as OctoPrint
does; rates, the link's longest gap between writes, CPU per line and the moves the
emulation queued (``once``, or how many it left out and queued twice). ``--repeat N``
makes each row N pairs of streams, the hosts taking turns to go first, reported as
medians, with the range of the pairs' CPU ratios (each host's CPU is its event loop's
thread time over the same lines). ``--instructions`` counts instead, with valgrind, the
instructions each host runs per line (the machine's load does not move that figure)::

    .venv/bin/python -m bench.stream_throughput --peer octoprint --peer-lines 3000 --repeat 5
    .venv/bin/python -m bench.stream_throughput --peer octoprint --peer-lines 2500 --instructions
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

from drivers.link.protocol import frame, parse_response
from drivers.link.streamer import Streamer, StreamerConfig
from drivers.link.transport import Transport, open_transport

# (the virtual-clock tables import what they need when they run, so that the wire table
# also runs, file given by path, against an older revision's drivers on PYTHONPATH)
# the virtual-clock hosts (the core and a send-and-wait host) are test support code
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def curved_perimeter(n: int, segment_mm: float = 0.3, radius_mm: float = 40.0) -> list[str]:
    """``n`` short G1 moves around a circle at 200 mm/s, as a fast curved perimeter."""
    step = segment_mm / radius_mm
    e_per_mm = 0.0332  # 0.45 x 0.2 mm bead on 1.75 mm filament
    lines = [f"G1 X{100 + radius_mm:.3f} Y100.000 F12000"]
    for i in range(1, n):
        a = i * step
        lines.append(f"G1 X{100 + radius_mm * math.cos(a):.3f} "
                     f"Y{100 + radius_mm * math.sin(a):.3f} E{segment_mm * e_per_mm:.5f}")
    return lines


@dataclass(frozen=True)
class Run:
    """One measured stream: lines, wall seconds, host CPU seconds, framed bytes, and the
    simulated printer's CPU seconds meanwhile (NaN where the platform cannot tell)."""

    lines: int
    wall_s: float
    cpu_s: float
    framed_bytes: int
    sim_cpu_s: float = math.nan

    @property
    def rate(self) -> float:
        """Lines per second."""
        return self.lines / self.wall_s

    @property
    def cpu_share(self) -> float:
        """Host CPU use as a fraction of one core."""
        return self.cpu_s / self.wall_s


class SimProcess:
    """``hostd simulate`` in a subprocess; ``path`` is its pseudo-terminal."""

    def __init__(self, baud: int, time_scale: float, latency_ms: float = 0.0) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hostd.app.cli", "simulate", "--baud", str(baud),
             "--time-scale", str(time_scale), "--latency-ms", str(latency_ms)],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        )
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()
        if not self.path:
            raise RuntimeError("hostd simulate printed no device path")

    def cpu_s(self) -> float:
        """CPU seconds the simulator process has used so far (every thread; NaN when
        ``/proc`` cannot tell)."""
        try:
            with open(f"/proc/{self.proc.pid}/stat", encoding="ascii") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            return math.nan
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        """Terminate the simulator and wait for it."""
        self.proc.terminate()
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


LAYER_LINES = 200  # lines handed to the link in one call, as the daemon hands a layer


async def send_in_layers(link: Streamer, lines: list[str]) -> None:
    """Hand ``lines`` to the link as the daemon's runner does: a layer's lines in one
    :meth:`~drivers.link.streamer.Streamer.send_many` (here blocks of LAYER_LINES)."""
    for start in range(0, len(lines), LAYER_LINES):
        await link.send_many((line, None) for line in lines[start:start + LAYER_LINES])


async def windowed(path: str, baud: int, lines: list[str]) -> Run:
    """The project's streamer: send-ahead window over the receive buffer."""
    config = StreamerConfig(temperature_interval_s=0)
    async with Streamer(await open_transport(path, baud), config) as link:
        await link.connect()
        cpu0, t0 = time.process_time(), time.perf_counter()
        await send_in_layers(link, lines)
        await link.drain()
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        first = link.stats.lines_sent - len(lines)
        framed = sum(len(frame(first + i + 1, line)) for i, line in enumerate(lines))
        if link.stats.resends:
            print(f"  note: {link.stats.resends} resend requests", file=sys.stderr)
    return Run(len(lines), wall, cpu, framed)


async def one_at_a_time(path: str, baud: int, lines: list[str]) -> Run:
    """The baseline: write one numbered line, wait for its ok, repeat."""
    transport = await open_transport(path, baud)
    try:
        await _settle(transport)
        await _exchange(transport, frame(0, "M110 N0"))
        cpu0, t0 = time.process_time(), time.perf_counter()
        framed = 0
        for i, line in enumerate(lines, 1):
            data = frame(i, line)
            framed += len(data)
            await _exchange(transport, data)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    finally:
        await transport.close()
    return Run(len(lines), wall, cpu, framed)


async def _settle(transport: Transport) -> None:
    """Read the boot banner until the line is quiet."""
    while True:
        try:
            await asyncio.wait_for(transport.readline(), 0.3)
        except TimeoutError:
            return


async def _exchange(transport: Transport, data: bytes) -> None:
    await transport.write(data)
    while True:
        response = parse_response(await transport.readline())
        if response.kind == "ok":
            return
        if response.kind in ("resend", "error"):
            raise RuntimeError(f"baseline got {response.raw!r}: the wire must be clean here")


def measure(
    baud: int, lines: list[str], time_scale: float, latency_ms: float = 0.0
) -> tuple[Run, Run]:
    """Windowed and one-at-a-time runs on fresh simulators at ``baud`` and ``latency_ms``."""
    results = []
    for method in (windowed, one_at_a_time):
        sim = SimProcess(baud, time_scale, latency_ms)
        try:
            before = sim.cpu_s()  # (includes its start and the host's connection: small)
            run = asyncio.run(method(sim.path, baud, lines))
            results.append(replace(run, sim_cpu_s=sim.cpu_s() - before))
        finally:
            sim.stop()
    return results[0], results[1]


def noisy_table(lines: list[str]) -> list[str]:
    """Rows of core vs send-and-wait rates on the virtual clock, clean and noisy."""
    from support.linkrun import run_core, run_send_and_wait

    from drivers.link.config import StreamerConfig as LinkConfig
    from drivers.sim.config import DIALECTS, SimulatorConfig, dialect

    base = {"baud": 250000, "latency_s": 0.001, "seed": 3}
    rows = [f"{'noise':>24} {'ok after':>8} {'core l/s':>9} {'% clean':>8} "
            f"{'send-wait l/s':>13} {'core/s&w':>8} {'resent':>7} {'max gap':>8} "
            f"{'exact':>6}"]
    clean = None
    cases = [("clean", "", 0.0, True)]
    for p in (0.02, 0.05, 0.10):
        for form in ("refuse", "resend"):
            for ok in (True, False):
                cases.append((f"{form} {100 * p:g} %", form, p, ok))
    # every firmware dialect with its own fault (resets, for the M110 dialects, at a
    # tenth of the rate: each costs a boot)
    for dialect_name, (_, fault) in DIALECTS.items():
        for p in (0.02, 0.05, 0.10):
            rate = p / 10 if fault == "reset" else p
            cases.append((f"{dialect_name} {100 * rate:g} %", dialect_name, rate, True))
    for name, form, p, ok in cases:
        if form in DIALECTS:
            sim = dialect(form, p, **base, keepalive_s=0.05, boot_delay_s=0.05)
        else:
            sim = SimulatorConfig(**base, ok_after_resend=ok,
                                  **({f"p_{form}": p} if form else {}))
        # the link's own probe interval (5 s): a stall shows in the longest gap
        link = LinkConfig(temperature_interval_s=0, ok_after_resend=ok, resync_quiet_s=0.01)
        core = run_core(lines, sim, link)
        wait = run_send_and_wait(lines, sim)
        clean = clean or core.rate
        exact = core.executed == lines and core.acked == lines and wait.executed == lines
        rows.append(f"{name:>24} {'yes' if ok else 'no':>8} {core.rate:>9.1f} "
                    f"{100 * core.rate / clean:>7.1f}% {wait.rate:>13.1f} "
                    f"{core.rate / wait.rate:>7.2f}x {core.stats.lines_resent:>7} "
                    f"{core.max_gap:>7.3f}s {'yes' if exact else 'NO':>6}")
        print(f"measured {name}, ok after resend {ok}", file=sys.stderr)
    return rows


def fault_suite_rate(count: int) -> str:
    """Wall-clock lines/s of the core through every fault kind at 1 % (virtual clock)."""
    from support.linkrun import run_core

    from drivers.link.config import StreamerConfig as LinkConfig
    from drivers.sim.config import SimulatorConfig

    kinds = ("corrupt_rx", "corrupt_tx", "drop_ok", "resend", "refuse", "busy")
    sim = SimulatorConfig(baud=250000, latency_s=0.001, keepalive_s=0.05, seed=5,
                          **{f"p_{k}": 0.01 for k in kinds})
    link = LinkConfig(temperature_interval_s=0, probe_after_s=0.05, probe_retries=1000,
                      resync_quiet_s=0.01)
    lines = curved_perimeter(count)
    t0, c0 = time.perf_counter(), time.process_time()
    run = run_core(lines, sim, link)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    exact = run.executed == lines and run.acked == lines
    return (f"fault suite on the core: {count} lines, every fault kind at 1 %, "
            f"{wall:.1f} s wall ({cpu:.1f} s CPU), {count / wall:,.0f} lines/s, "
            f"exactly once: {exact}")


# -- an emulation nobody here wrote: OctoPrint's virtual printer ------------------------------

OCTOPRINT = "octoprint==1.11.8"
CACHE = Path(__file__).resolve().parent / ".cache"


def octoprint_python() -> str:
    """The Python of a virtual environment of its own with OctoPrint (AGPL: a benchmark
    tool's peer, never a dependency of the package), created under ``bench/.cache/``."""
    venv = CACHE / "octoprint-venv"
    python = venv / "bin" / "python"
    if not python.exists():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    probe = subprocess.run([str(python), "-c", "import octoprint"], capture_output=True)
    if probe.returncode != 0:
        subprocess.run([str(python), "-m", "pip", "install", "-q", OCTOPRINT], check=True)
    return str(python)


class PeerProcess:
    """``bench/octoprint_peer.py`` (OctoPrint's virtual printer on a pseudo-terminal) in a
    process of its own; ``moves()`` reads the moves it queued once it has stopped."""

    def __init__(self, python: str, resend_ratio: int) -> None:
        self.log = CACHE / f"octoprint-moves-{os.getpid()}.txt"
        self.proc = subprocess.Popen(
            [python, str(Path(__file__).resolve().parent / "octoprint_peer.py"),
             "--resend-ratio", str(resend_ratio), "--log", str(self.log)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
            text=True,
        )
        assert self.proc.stdout is not None
        self.path = self.proc.stdout.readline().strip()
        if not self.path:
            raise RuntimeError("the OctoPrint peer printed no device path")

    def stop(self) -> list[str]:
        """Stop the emulation; the moves it queued, in order."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        moves = self.log.read_text(encoding="utf-8").splitlines() if self.log.exists() else []
        self.log.unlink(missing_ok=True)
        return moves


@dataclass(frozen=True)
class PeerRun:
    """One stream to the emulation: the measured run, the longest gap between two writes
    while streaming, and the moves the emulation queued."""

    run: Run
    max_gap_s: float
    moves: list[str]


async def windowed_peer(path: str, lines: list[str]) -> tuple[Run, float]:
    """The project's link, at its defaults (5 s before a probe after silence)."""
    config = StreamerConfig(temperature_interval_s=0)
    stamps: list[float] = []
    transport = await open_transport(path, 250000)
    write = transport.write_now  # (write() goes through it too, as the read callback does)

    def timed(data: bytes) -> None:
        stamps.append(time.perf_counter())
        write(data)

    transport.write_now = timed  # type: ignore[method-assign]
    async with Streamer(transport, config) as link:
        await link.connect()
        first = len(stamps)
        cpu0, t0 = time.thread_time(), time.perf_counter()
        await send_in_layers(link, lines)
        await link.drain()
        wall, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
    gaps = [b - a for a, b in zip(stamps[first:], stamps[first + 1:], strict=False)]
    return Run(len(lines), wall, cpu, 0), max(gaps, default=0.0)


async def send_and_wait_peer(path: str, lines: list[str]) -> tuple[Run, float]:
    """One line, then its ok, as OctoPrint streams: a request for a line already sent
    replays from it (the ok after the request skipped); one for the next line, not yet
    sent, is ignored and its ok taken for the line's."""
    transport = await open_transport(path, 250000)
    try:
        await _settle(transport)
        await transport.write(frame(0, "M110 N0"))
        while parse_response(await transport.readline()).kind != "ok":
            pass
        cpu0, t0 = time.thread_time(), time.perf_counter()
        n = 1
        while n <= len(lines):
            await transport.write(frame(n, lines[n - 1]))
            replay: int | None = None
            while True:
                response = parse_response(await transport.readline())
                if response.kind == "resend" and response.line is not None \
                        and response.line <= n:
                    replay = response.line
                elif response.kind == "ok":
                    break
            n = replay if replay is not None else n + 1
        wall, cpu = time.perf_counter() - t0, time.thread_time() - cpu0
    finally:
        await transport.close()
    return Run(len(lines), wall, cpu, 0), 0.0


def peer_table(count: int, ratios: list[int], repeat: int = 1) -> list[str]:
    """Rows of the project's link vs a send-and-wait host on OctoPrint's virtual printer,
    clean and at each resend ratio, a fresh emulation per stream.

    Each row is ``repeat`` pairs of streams, the two hosts taking turns to go first (so a
    change of the machine's load falls on both alike), each host's CPU time measured the
    same way: the event loop's thread (:func:`time.thread_time`), from the first job line
    to the last acknowledged. The row gives medians over the pairs, the CPU ratio as the
    median of the pairs' ratios with their range, the longest gap of any of the link's
    streams and the worst exactness of each host.
    """
    python = octoprint_python()
    moves = curved_perimeter(count)
    # absolute positions: the emulation starts relative, and sleeps a tenth of each move's
    # time (0.3 mm segments read as 140 mm moves took 70 ms each)
    lines = ["G90", *moves]
    rows = [f"{'resend %':>8} {'hostd l/s':>9} {'% clean':>8} {'s&w l/s':>8} "
            f"{'hostd/s&w':>9} {'max gap':>8} {'hostd us/l':>10} {'s&w us/l':>9} "
            f"{'CPU ratio':>9} {'CPU ratio range':>15} {'hostd run':>13} {'s&w run':>13}"]
    clean = None
    hosts = (windowed_peer, send_and_wait_peer)
    for ratio in ratios:
        pairs: list[tuple[PeerRun, PeerRun]] = []
        for turn in range(max(1, repeat)):
            runs: dict[str, PeerRun] = {}
            for host in hosts if turn % 2 == 0 else hosts[::-1]:
                peer = PeerProcess(python, ratio)
                try:
                    run, gap = asyncio.run(host(peer.path, lines))
                finally:
                    queued = peer.stop()
                runs[host.__name__] = PeerRun(run, gap, queued)
                print(f"measured {host.__name__} at {ratio} % ({turn + 1}/{repeat})",
                      file=sys.stderr)
            pairs.append((runs[windowed_peer.__name__], runs[send_and_wait_peer.__name__]))
        rows.append(_peer_row(ratio, pairs, moves, clean))
        clean = clean or statistics.median(ours.run.rate for ours, _ in pairs)
    return rows


def _peer_row(ratio: int, pairs: list[tuple[PeerRun, PeerRun]], moves: list[str],
              clean: float | None) -> str:
    """One row of :func:`peer_table`: medians over ``pairs`` (the link's run, the
    send-and-wait host's)."""
    n = pairs[0][0].run.lines
    ours_rate = statistics.median(ours.run.rate for ours, _ in pairs)
    wait_rate = statistics.median(wait.run.rate for _, wait in pairs)
    ours_us = statistics.median(1e6 * ours.run.cpu_s / n for ours, _ in pairs)
    wait_us = statistics.median(1e6 * wait.run.cpu_s / n for _, wait in pairs)
    cpu_ratios = [ours.run.cpu_s / wait.run.cpu_s for ours, wait in pairs]
    gap = max(ours.max_gap_s for ours, _ in pairs)
    spread = f"{min(cpu_ratios):.2f}-{max(cpu_ratios):.2f}x"
    exact_ours = {_exactness(ours.moves, moves) for ours, _ in pairs}
    exact_wait = {_exactness(wait.moves, moves) for _, wait in pairs}
    return (f"{ratio:>8} {ours_rate:>9.1f} {100 * ours_rate / (clean or ours_rate):>7.1f}% "
            f"{wait_rate:>8.1f} {ours_rate / wait_rate:>8.2f}x "
            f"{gap:>7.3f}s {ours_us:>10.0f} {wait_us:>9.0f} "
            f"{statistics.median(cpu_ratios):>8.2f}x {spread:>15} "
            f"{_worst(exact_ours):>13} {_worst(exact_wait):>13}")


def _worst(exactness: set[str]) -> str:
    """``once`` when every stream was; else the other outcomes, joined."""
    others = sorted(e for e in exactness if e != "once")
    return "/".join(others) if others else "once"


def one_peer_stream(host: str, count: int, ratio: int) -> str:
    """One stream of ``host`` (``link`` or ``send-and-wait``) to a fresh emulation at
    ``ratio`` %: its CPU per line (us), rate and longest gap, on one line."""
    lines = ["G90", *curved_perimeter(count)]
    peer = PeerProcess(octoprint_python(), ratio)
    try:
        run, gap = asyncio.run(
            (windowed_peer if host == "link" else send_and_wait_peer)(peer.path, lines))
    finally:
        peer.stop()
    return f"{1e6 * run.cpu_s / len(lines):.1f} {run.rate:.1f} {gap:.3f}"


def instructions_table(count: int, ratios: list[int]) -> list[str]:
    """Instructions per line each host runs, counted by valgrind (user space, the host's
    process only): each host streams ``count // 5`` and ``count`` lines, and the
    difference of the two counts over the difference of the lines is its cost of a
    line, free of the start, the connection and the machine's load. (The kernel's share,
    the system calls, is not counted: the two hosts make about as many.)"""
    short = max(1, count // 5)
    rows = [f"{'resend %':>8} {'hostd kinstr/l':>14} {'s&w kinstr/l':>12} {'ratio':>6}"]
    for ratio in ratios:
        per_line = []
        for host in ("link", "send-and-wait"):
            counts = [_instructions(host, n, ratio) for n in (short, count)]
            per_line.append((counts[1] - counts[0]) / (count - short))
            print(f"counted {host} at {ratio} %", file=sys.stderr)
        ours, wait = per_line
        rows.append(f"{ratio:>8} {ours / 1e3:>14.1f} {wait / 1e3:>12.1f} {ours / wait:>5.2f}x")
    return rows


def _instructions(host: str, count: int, ratio: int) -> int:
    """Instructions of one :func:`one_peer_stream` process, counted by valgrind."""
    result = subprocess.run(
        ["valgrind", "--tool=cachegrind", "--cache-sim=no", "--cachegrind-out-file=/dev/null",
         sys.executable, "-m", "bench.stream_throughput", "--peer", "octoprint",
         "--one", host, "--peer-lines", str(count), "--resend-ratios", str(ratio)],
        capture_output=True, text=True, check=True,
        cwd=Path(__file__).resolve().parents[1])
    for line in result.stderr.splitlines():
        if "I" in line and "refs:" in line:
            return int(line.rsplit(":", 1)[1].replace(",", "").strip())
    raise RuntimeError(f"valgrind reported no instruction count: {result.stderr[-300:]}")


def _exactness(moves: list[str], lines: list[str]) -> str:
    """``once`` when the emulation queued every line once, in order; else how many it
    left out and how many it queued twice (``-3 +0``)."""
    if moves == lines:
        return "once"
    seen: dict[str, int] = {}
    for move in moves:
        seen[move] = seen.get(move, 0) + 1
    missing = sum(1 for line in lines if line not in seen)
    twice = sum(c - 1 for c in seen.values() if c > 1)
    order = "" if [m for m in moves if m in set(lines)] == [ln for ln in lines if ln in seen] \
        else " order!"
    return f"-{missing} +{twice}{order}"


def main(argv: list[str] | None = None) -> int:
    """Measure and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=5000)
    parser.add_argument("--bauds", type=int, nargs="+", default=[115200, 250000])
    parser.add_argument("--latencies-ms", type=float, nargs="+", default=[0.0, 1.0, 4.0],
                        help="one-way link latencies to measure at (milliseconds)")
    parser.add_argument("--time-scale", type=float, default=0.0,
                        help="simulated printer speed (0: moves take no time, the wire limits)")
    parser.add_argument("--noisy-lines", type=int, default=20000,
                        help="lines per noisy row on the virtual clock (0: no noisy table)")
    parser.add_argument("--fault-lines", type=int, default=100000,
                        help="lines through the fault suite on the core (0: skip)")
    parser.add_argument("--skip-wire", action="store_true",
                        help="skip the table on the pty simulator")
    parser.add_argument("--peer", choices=["simulator", "octoprint"], default="simulator",
                        help="octoprint: only the rows against OctoPrint's virtual printer")
    parser.add_argument("--peer-lines", type=int, default=2000,
                        help="lines per stream against the OctoPrint peer")
    parser.add_argument("--resend-ratios", type=int, nargs="+", default=[0, 2, 5, 10],
                        help="the OctoPrint peer's resend ratios (percent)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="measure each speed and latency this many times (a row each); "
                             "with --peer octoprint, the pairs of streams per row (medians)")
    parser.add_argument("--instructions", action="store_true",
                        help="with --peer octoprint: instructions per line of each host, "
                             "counted by valgrind (Debian package valgrind)")
    parser.add_argument("--one", choices=["link", "send-and-wait"],
                        help="with --peer octoprint: one stream of that host (for --instructions)")
    args = parser.parse_args(argv)
    if args.peer == "octoprint" and args.one:
        print(one_peer_stream(args.one, args.peer_lines, args.resend_ratios[0]))
        return 0
    if args.peer == "octoprint" and args.instructions:
        print(f"instructions per line, {args.peer_lines // 5} and {args.peer_lines} lines to "
              f"OctoPrint's virtual printer ({OCTOPRINT}), counted by valgrind")
        print("\n".join(instructions_table(args.peer_lines, args.resend_ratios)))
        return 0
    if args.peer == "octoprint":
        print(f"{args.peer_lines} short G1 moves to OctoPrint's virtual printer ({OCTOPRINT}) "
              "on a pseudo-terminal, link defaults (5 s probe interval), "
              f"medians of {max(1, args.repeat)} interleaved pair(s) per row, "
              f"load {os.getloadavg()[0]:.1f}")
        print("\n".join(peer_table(args.peer_lines, args.resend_ratios, args.repeat)))
        return 0
    if args.noisy_lines:
        rows = noisy_table(curved_perimeter(args.noisy_lines))
        print(f"{args.noisy_lines} short G1 moves, virtual-clock Marlin, 250000 baud, 1 ms")
        print("\n".join(rows))
    if args.fault_lines:
        print(fault_suite_rate(args.fault_lines))
    if args.skip_wire:
        return 0
    lines = curved_perimeter(args.lines)
    header = (f"{'baud':>7} {'latency':>7} {'wire l/s':>9} {'window l/s':>10} {'% wire':>7} "
              f"{'1-at-a-time l/s':>15} {'% wire':>7} {'speedup':>7} {'host CPU':>9} "
              f"{'host us/l':>9} {'sim us/l':>8} {'1-a-t host us/l':>15} {'bytes/line':>10}")
    rows = []
    cases = [(b, lat) for b in args.bauds for lat in args.latencies_ms]
    for baud, latency in cases * max(1, args.repeat):
        win, base = measure(baud, lines, args.time_scale, latency)
        mean_len = win.framed_bytes / win.lines
        wire = baud / 10 / mean_len
        rows.append(
            f"{baud:>7} {latency:>5g}ms {wire:>9.1f} "
            f"{win.rate:>10.1f} {100 * win.rate / wire:>6.1f}% "
            f"{base.rate:>15.1f} {100 * base.rate / wire:>6.1f}% {win.rate / base.rate:>6.2f}x "
            f"{100 * win.cpu_share:>8.1f}% {1e6 * win.cpu_s / win.lines:>9.0f} "
            f"{1e6 * win.sim_cpu_s / win.lines:>8.0f} {1e6 * base.cpu_s / base.lines:>15.0f} "
            f"{mean_len:>10.1f}"
        )
        print(f"measured {baud} baud, {latency:g} ms latency", file=sys.stderr)
    print(f"{args.lines} short G1 moves (0.3 mm at 200 mm/s), simulated printer "
          f"time scale {args.time_scale:g}")
    print(header)
    for row in rows:
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
