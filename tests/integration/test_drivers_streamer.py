"""The streamer against the simulated printer and a scripted Marlin-like responder on a pty."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable

import pytest
from support.linkrun import arc_job as job
from support.streaming import (
    FAST,
    INTERNAL,
    ScriptedPrinter,
    job_lines,
    scripted,
    sim_config,
    stream_job,
    stream_scripted,
)
from support.waiting import until

from drivers.link.streamer import (
    HALTED,
    Ack,
    AckChannel,
    LinkError,
    StreamCancelled,
    Streamer,
    StreamerConfig,
)
from drivers.link.transport import open_transport
from drivers.sim.printer import SimulatedPrinter, SimulatorConfig

# -- basic streaming -------------------------------------------------------------------------

def test_streams_a_job_exactly_once_in_order_with_handshake():
    lines = job(500)
    with SimulatedPrinter(sim_config()) as sim:
        link = asyncio.run(stream_job(sim, lines))
        executed = list(sim.executed)
    assert executed[0] == "M110 N0"
    assert "M115" in executed
    assert "M155 S1" in executed  # the simulator offers AUTOREPORT_TEMP
    assert job_lines(executed) == lines
    assert link.acked == len(lines)
    assert "EMERGENCY_PARSER" in link.capable
    assert link.firmware.startswith("Marlin")


def test_acknowledged_tags_are_the_lines_the_printer_executed_in_order_across_resends():
    lines = job(300)
    tags: list[object] = []

    async def run(sim: SimulatedPrinter) -> Streamer:
        async with Streamer(await open_transport(sim.path, 250000), FAST) as link:
            with link.acknowledgements() as channel:

                async def follow() -> None:
                    async for ack in channel:
                        assert ack.command == lines[ack.tag]
                        tags.append(ack.tag)

                follower = asyncio.create_task(follow(), name="follower")
                await link.connect()
                for index, line in enumerate(lines):
                    await link.send(line, tag=index)
                await link.drain()
            await follower  # the channel closed: every ack delivered was read
        return link

    with SimulatedPrinter(sim_config(p_corrupt_rx=0.05, seed=3)) as sim:
        link = asyncio.run(run(sim))
        executed = job_lines(list(sim.executed))
    assert link.stats.resends > 0  # the noise made the printer ask for lines again
    assert [lines[tag] for tag in tags] == executed
    assert tags == list(range(len(lines)))


class SuspendingWrites:
    """A transport whose write yields to the event loop before writing (a wrapper that
    does I/O of its own would): the streamer's reader, writer and ``send()`` then write
    concurrently, and the bytes must still leave in the order the core handed them out."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.name = inner.name

    async def write(self, data: bytes) -> None:
        await asyncio.sleep(0)
        await self.inner.write(data)

    async def readline(self) -> str:
        return await self.inner.readline()

    async def close(self) -> None:
        await self.inner.close()


def test_a_transport_whose_write_suspends_gets_every_line_once_in_order():
    lines = job(300)

    async def run(sim: SimulatedPrinter) -> Streamer:
        transport = SuspendingWrites(await open_transport(sim.path, 250000))
        async with Streamer(transport, FAST) as link:  # type: ignore[arg-type]
            await link.connect()
            for line in lines:
                await link.send(line)
            await link.drain()
        return link

    with SimulatedPrinter(sim_config(p_corrupt_rx=0.05, seed=4)) as sim:
        link = asyncio.run(run(sim))
        executed = job_lines(list(sim.executed))
    assert link.stats.resends > 0  # replays went out beside new lines
    assert executed == lines


def test_at_the_wire_limit_the_receive_buffer_never_overflows():
    lines = job(1500)
    # a probe goes out past the window: on a loaded machine the simulator may be starved
    # for longer than FAST's probe delay, and a probe then overflows its buffer
    config = StreamerConfig(**{**FAST.__dict__, "probe_after_s": 1.0})
    with SimulatedPrinter(sim_config(baud=250000)) as sim:
        link = asyncio.run(stream_job(sim, lines, config))
        stats = sim.stats()
        executed = list(sim.executed)
    assert job_lines(executed) == lines
    assert stats.rx_overflow_bytes == 0
    assert stats.errors == 0
    assert link.stats.resends == 0


def test_advanced_ok_teaches_the_command_buffer_size():
    lines = job(400)
    with SimulatedPrinter(sim_config(advanced_ok=True, bufsize=8, baud=250000)) as sim:
        link = asyncio.run(stream_job(sim, lines))
        executed = list(sim.executed)
    assert job_lines(executed) == lines
    assert link.core.window.max_lines >= 8


def test_line_numbers_restart_with_m110_before_they_grow_large():
    lines = job(2600)
    config = StreamerConfig(**{**FAST.__dict__, "renumber_at": 1000})
    with SimulatedPrinter(sim_config(p_corrupt_rx=0.01, seed=5)) as sim:
        link = asyncio.run(stream_job(sim, lines, config))
        executed = list(sim.executed)
        last = sim.last_line
    assert job_lines(executed) == lines
    assert link.stats.renumbers == 2
    assert executed.count("M110 N0") == 3
    assert last < 1000


# -- resend sanity with a scripted printer ---------------------------------------------------

def test_resend_with_lost_digits_replays_the_right_line():
    failed = []

    def answer(number: int, command: str) -> list[str] | None:
        if number == 15 and not failed:
            failed.append(number)
            # the line is refused; the reply lost a digit: 14 -> 4, 15 -> 05
            return ["Error:checksum mismatch, Last Line: 4", "Resend: 05", "ok"]
        return None

    lines = job(40)
    with scripted(answer) as printer:
        link = asyncio.run(stream_scripted(printer, lines))
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
    assert executed == lines
    assert link.stats.lines_resent >= 1


def test_resend_for_a_line_never_sent_is_not_obeyed():
    def answer(number: int, command: str) -> list[str] | None:
        if number == 10:
            return ["ok", "Resend: 99999"]
        return None

    lines = job(30)
    with scripted(answer) as printer:
        link = asyncio.run(stream_scripted(printer, lines))
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
    assert executed == lines
    assert link.stats.lines_resent == 0


def test_lost_oks_and_a_refused_probe_are_recovered_without_a_probe_storm():
    # the oks of four lines are lost, filling the window; the probe sent to find out is
    # refused (corrupted on the wire), so its replay is due while the window looks full
    lost = set()
    probes_refused = []

    def answer(number: int, command: str) -> list[str] | None:
        if 20 <= number < 24 and number not in lost:
            lost.add(number)
            return ["echo:ok lost"]  # executed, its ok never arrives
        if command == "M105" and not probes_refused:
            probes_refused.append(number)
            return [f"Error:checksum mismatch, Last Line: {number - 1}",
                    f"Resend: {number}", "ok"]
        return None

    lines = [f"G1 X{i}" for i in range(60)]
    with scripted(answer) as printer:
        link = asyncio.run(stream_scripted(printer, lines))
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
    assert executed == lines
    assert probes_refused
    assert len(lost) == 4
    # the probe's replay goes out past the full window and its answer resyncs the count;
    # a probe numbered ahead of the replay would be refused again and again
    assert link.stats.probes <= 4
    assert link.acked == len(lines)


class SlowRenumber(ScriptedPrinter):
    """Answers the ``M110`` that renumbers mid-stream late, then pauses again before it
    reads on: the link writes the M110 again, and sees both oks with a line between."""

    def __init__(self, pause_s: float) -> None:
        self.pause_s = pause_s
        self.m110s = 0
        super().__init__()

    def _line(self, text: str) -> None:
        if "M110" in text:
            self.m110s += 1
            if self.m110s == 2:  # the first is the handshake's
                threading.Event().wait(self.pause_s)
                super()._line(text)
                threading.Event().wait(self.pause_s / 2)
                return
        super()._line(text)


def test_a_late_ok_for_a_rewritten_m110_never_acknowledges_a_job_line():
    # the M110 is written again after renumber_retry_s of silence; every ok then comes,
    # and none may be counted for a line of the new numbering
    config = StreamerConfig(**{**FAST.__dict__, "renumber_retry_s": 0.1, "renumber_at": 1000})
    lines = [f"G1 X{i}" for i in range(1100)]
    printer = SlowRenumber(pause_s=0.4)
    early: list[str] = []

    async def run() -> Streamer:
        class Checked(AckChannel):
            def put(self, ack: Ack) -> None:  # called by the reader as the ok is read
                if ack.command not in printer.executed:  # acknowledged before it ran
                    early.append(ack.command)
                super().put(ack)

        async with Streamer(await open_transport(printer.path, 115200), config) as link:
            with link.acknowledgements(Checked()):
                await link.connect()
                for line in lines:
                    await link.send(line)
                await link.drain()
        return link

    try:
        link = asyncio.run(run())
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
        m110s = printer.m110s
    finally:
        printer.close()
    assert m110s >= 3  # handshake, renumber, and the renumber written again
    assert executed == lines
    assert early == []
    assert link.acked == len(lines)


class ResetAfterRefusal(ScriptedPrinter):
    """Refuses line 30 once, answering ``refusal(text)`` (noise has garbled part of the
    exchange), then reboots on the next numbered line it reads: ``start``, line numbers
    forgotten."""

    def __init__(self, refusal: Callable[[str], list[str]]) -> None:
        self.refusal = refusal
        self.refused = False
        self.reset_next = False
        super().__init__()

    def _line(self, text: str) -> None:
        if not text.startswith("N"):
            super()._line(text)
        elif self.reset_next:
            self.reset_next = False
            self.received.append(text)
            self.last_n = 0
            self._send(["start"])
        elif text.startswith("N30 ") and not self.refused:
            self.refused = self.reset_next = True
            self.received.append(text)
            self._send(self.refusal(text))
        else:
            super()._line(text)


def _unknown_command(text: str) -> list[str]:
    """The reply to a framed line whose leading ``N`` noise turned into ``O`` (one bit): run
    as an unknown command, without its checksum, and answered ``ok``."""
    return [f'echo:Unknown command: "O{text[1:].rsplit("*", 1)[0]}"', "ok"]


@pytest.mark.parametrize("refusal", [
    # one character of the message changed: still the error of a refused line
    lambda _: ["Error:Line Numbes is not Last Line Number+1, Last Line: 29", "Resend: 30", "ok"],
    # the Resend line lost to noise: the ok right after the error is still its ok
    lambda _: ["Error:checksum mismatch, Last Line: 29", "Resent 3o", "ok"],
    # the line's N garbled: the printer runs it as an unknown command
    _unknown_command,
], ids=["garbled-error", "lost-resend", "garbled-n"])
def test_the_ok_after_a_garbled_refusal_never_counts_for_a_line(refusal):
    # counted for a line, that ok would make the link take the refused line as done,
    # and a reboot before anything else corrected the count would lose it for good
    lines = [f"G1 X{i}" for i in range(60)]
    printer = ResetAfterRefusal(refusal)
    try:
        link = asyncio.run(stream_scripted(printer, lines))
        executed = [c for c in printer.executed if c.split()[0] not in INTERNAL]
    finally:
        printer.close()
    assert printer.refused
    assert executed == lines
    assert link.acked == len(lines)


def test_no_autoreport_means_m105_polling():
    config = StreamerConfig(**{**FAST.__dict__, "temperature_interval_s": 0.05})
    reports = []

    async def run(printer: ScriptedPrinter) -> None:
        async with Streamer(await open_transport(printer.path, 115200), config) as link:
            link.on_temperature = reports.append
            await link.connect()
            await until(lambda: sum("M105" in line for line in list(printer.received)) >= 3
                        and reports, 10, "three M105 polls answered")
            await link.drain()

    with scripted() as printer:
        asyncio.run(run(printer))
        received = list(printer.received)
    assert not any("M155" in line for line in received)
    assert sum("M105" in line for line in received) >= 3
    assert reports
    assert reports[0].temperatures["T"] == (20.0, 0.0)


def test_silent_printer_is_probed_then_the_link_fails_and_stops_sending():
    silent_from = 20

    def answer(number: int, command: str) -> list[str] | None:
        return [] if number >= silent_from or command == "M105" else None

    config = StreamerConfig(**{**FAST.__dict__, "probe_after_s": 0.05, "probe_retries": 2})
    errors: list[str] = []

    async def run(printer: ScriptedPrinter) -> None:
        async with Streamer(await open_transport(printer.path, 115200), config) as link:
            link.on_error = errors.append
            await link.connect()
            with pytest.raises(LinkError):
                for line in job(200):
                    await link.send(line)
                await link.drain()
            assert link.state == "error"
            with pytest.raises(LinkError):
                await link.send("G1 X1")

    with scripted(answer) as printer:
        asyncio.run(run(printer))
        received = list(printer.received)
    assert errors
    assert "not responding" in errors[-1]
    probes = [i for i, line in enumerate(received) if "M105" in line]
    assert len(probes) == 2
    # after the first probe, nothing but probes went out
    assert all("M105" in line for line in received[probes[0]:])


def test_firmware_without_ok_after_resend():
    lines = job(3000)
    config = StreamerConfig(**{**FAST.__dict__, "ok_after_resend": False})
    with SimulatedPrinter(sim_config(ok_after_resend=False, p_corrupt_rx=0.01, seed=2)) as sim:
        asyncio.run(stream_job(sim, lines, config))
        executed = list(sim.executed)
    assert job_lines(executed) == lines


def test_wrong_guess_about_ok_after_resend_costs_time_not_lines():
    lines = job(2000)
    with SimulatedPrinter(sim_config(ok_after_resend=False, p_corrupt_rx=0.01, seed=4)) as sim:
        asyncio.run(stream_job(sim, lines))
        executed = list(sim.executed)
    assert job_lines(executed) == lines


# -- long commands ---------------------------------------------------------------------------

def test_heating_and_homing_never_trip_the_timeout():
    # M109/M190 take seconds of wall time here; probes are due after 0.1 s of silence and
    # the link would give up after one unanswered probe, if busy and temperature lines did
    # not count as signs of life
    config = StreamerConfig(**{**FAST.__dict__, "probe_after_s": 0.1, "probe_retries": 1,
                               "long_command_timeout_s": 0.3})
    lines = ["M140 S60", "M104 S200", "G28", "M190 S60", "M109 S200", *job(50)]
    errors: list[str] = []
    with SimulatedPrinter(sim_config(time_scale=0.02, keepalive_s=2.0)) as sim:
        link = asyncio.run(stream_job(sim, lines, config, errors=errors))
        executed = list(sim.executed)
    assert job_lines(executed) == lines
    assert errors == []
    assert link.state != "error"


# -- control ---------------------------------------------------------------------------------

def _slow_sim() -> SimulatorConfig:
    return sim_config(time_scale=0.05)


# moves take wall time here: silence while the planner is full is normal
SLOW = StreamerConfig(**{**FAST.__dict__, "probe_after_s": 0.5})


async def _wait_acked(link: Streamer, count: int) -> None:
    while link.acked < count:
        assert link.state not in ("error", "halted"), link.error
        await asyncio.sleep(0.01)


def test_pause_parks_and_resume_continues_exactly_where_it_stopped():
    lines = job(300)
    park = ("G91", "G1 Z5 F600", "G90")
    unpark = ("G91", "G1 Z-5 F600", "G90")

    # that nothing of the job runs while paused is proved on the virtual clock
    # (tests/unit/test_drivers_pause.py); here the shell's pause and resume on the wire
    async def run(sim: SimulatedPrinter) -> None:
        async with Streamer(await open_transport(sim.path, 250000), SLOW) as link:
            await link.connect()

            async def producer() -> None:
                for line in lines:
                    await link.send(line)

            task = asyncio.create_task(producer(), name="producer")
            await _wait_acked(link, 100)
            await link.pause(park=park)
            assert link.state == "paused"
            await link.resume(unpark=unpark)
            await task
            await link.drain()

    with SimulatedPrinter(_slow_sim()) as sim:
        asyncio.run(run(sim))
        executed = list(sim.executed)
    body = job_lines(executed)
    cut = body.index("G91")
    assert body[cut:cut + 3] == list(park)
    assert body[cut + 3:cut + 6] == list(unpark)
    assert body[:cut] + body[cut + 6:] == lines
    assert 100 <= cut < 300


def test_cancel_sends_end_gcode_and_refuses_further_lines():
    lines = job(400)
    end = ("M104 S0", "M140 S0", "M84")

    async def run(sim: SimulatedPrinter) -> None:
        async with Streamer(await open_transport(sim.path, 250000), SLOW) as link:
            await link.connect()

            async def producer() -> None:
                for line in lines:
                    await link.send(line)

            task = asyncio.create_task(producer(), name="producer")
            await _wait_acked(link, 50)
            await link.cancel(end)
            with pytest.raises(StreamCancelled):
                await task
            with pytest.raises(StreamCancelled):
                await link.send("G1 X0")
            link.begin_job()  # the next job on the same link
            for line in lines[:5]:
                await link.send(line)
            await link.drain()

    with SimulatedPrinter(_slow_sim()) as sim:
        asyncio.run(run(sim))
        body = job_lines(sim.executed)
    assert body[-5:] == lines[:5]
    body = body[:-5]
    assert body[-3:] == list(end)
    done = body[:-3]
    assert done == lines[:len(done)]
    assert 50 <= len(done) < len(lines)


@pytest.mark.parametrize("parser", [True, False])
def test_emergency_stop_halts_the_printer_at_once(parser):
    lines = job(400)

    async def run(sim: SimulatedPrinter) -> Streamer:
        async with Streamer(await open_transport(sim.path, 250000), SLOW) as link:
            await link.connect()

            async def producer() -> None:
                for line in lines:
                    await link.send(line)

            task = asyncio.create_task(producer(), name="producer")
            await _wait_acked(link, 30)
            await link.emergency_stop()
            with pytest.raises(LinkError):
                await task
            with pytest.raises(LinkError):
                await link.send("G1 X0")
            await until(lambda: "M112" in list(sim.executed), 5, "the M112 carried out")
            return link

    with SimulatedPrinter(sim_config(time_scale=0.05, emergency_parser=parser)) as sim:
        link = asyncio.run(run(sim))
        executed = list(sim.executed)
        stats = sim.stats()
    assert link.state == HALTED
    assert "M112" in executed
    if not parser:
        # never into a full receive buffer (whose overrun lost the M112's end), and no job
        # line written after it (out of band, the parser reads it even from an overrun)
        assert stats.rx_overflow_bytes == 0
        assert stats.errors == 0
        stop_number = max(n for n, (cmd, _) in link.core.writer.history.items() if cmd == "M112")
        assert all(internal for n, (_, internal) in link.core.writer.history.items()
                   if n > stop_number)
    body = job_lines(executed)
    stop = body.index("M112")
    assert body[:stop] == lines[:stop]
    assert stop < len(lines)
    assert body[stop + 1:] == []  # nothing after the stop


# -- unplug and reconnect --------------------------------------------------------------------

@pytest.mark.parametrize("reset_on_open", [False, True])
def test_unplug_mid_stream_reports_at_once_and_reconnects(tmp_path, reset_on_open):
    link_path = str(tmp_path / "printer")
    lines = job(1500)
    errors: list[str] = []
    seen: list[float] = []

    async def run(sim: SimulatedPrinter) -> Streamer:
        async with Streamer(await open_transport(link_path, 250000), FAST) as link:
            loop = asyncio.get_running_loop()
            link.on_error = lambda text: (errors.append(text), seen.append(loop.time()))
            await link.connect()
            for i, line in enumerate(lines):
                if i == 700:
                    await link.drain()  # no reply in transit: nothing to lose
                    unplugged = loop.time()
                    sim.disconnect()
                await link.send(line)
            await link.drain()
            assert seen
            assert seen[0] - unplugged < 1.0
            return link

    config = sim_config(baud=250000, link_path=link_path, reconnect_delay_s=0.05,
                        reset_on_open=reset_on_open)
    with SimulatedPrinter(config) as sim:
        link = asyncio.run(run(sim))
        executed = list(sim.executed)
    assert job_lines(executed) == lines
    assert link.stats.reconnects == 1
    assert any("link lost" in e for e in errors)


def test_port_lost_for_good_gives_an_error_state():
    config = StreamerConfig(**{**FAST.__dict__, "reconnect_attempts": 2})

    async def run(sim: SimulatedPrinter) -> Streamer:
        async with Streamer(await open_transport(sim.path, 250000), config) as link:
            await link.connect()
            sim.stop()
            with pytest.raises(LinkError):
                for line in job(5000):
                    await link.send(line)
            return link

    sim = SimulatedPrinter(sim_config(time_scale=0.05))
    sim.start()
    link = asyncio.run(run(sim))
    assert link.state == "error"
    assert "link lost" in (link.error or "")


def test_a_batch_is_acknowledged_line_by_line_with_its_tags_across_resends():
    lines = job(300)
    tags: list[object] = []

    async def run(sim: SimulatedPrinter) -> tuple[int | None, int]:
        async with Streamer(await open_transport(sim.path, 250000), FAST) as link:
            with link.acknowledgements() as channel:

                async def follow() -> None:
                    async for ack in channel:
                        tags.append(ack.tag)

                follower = asyncio.create_task(follow(), name="follower")
                await link.connect()
                last = None
                for start in range(0, len(lines), 120):  # layers of up to 120 lines
                    block = lines[start:start + 120]
                    last = await link.send_many(
                        (line, start + i) for i, line in enumerate(block))
                assert await link.send_many([]) is None
                await link.drain()
            await follower
        return last, link.stats.resends

    with SimulatedPrinter(sim_config(p_corrupt_rx=0.05, seed=5)) as sim:
        last, resends = asyncio.run(run(sim))
        executed = job_lines(list(sim.executed))
    assert resends > 0  # the noise made the printer ask for lines again
    assert executed == lines
    assert tags == list(range(len(lines)))
    assert last is not None
    assert last > len(lines)  # the last line's number (the handshake's lines before)


def test_cancel_drops_what_a_batch_still_holds_and_the_batch_raises():
    lines = job(400)
    end = ("M104 S0", "M140 S0", "M84")

    async def run(sim: SimulatedPrinter) -> None:
        async with Streamer(await open_transport(sim.path, 250000), SLOW) as link:
            await link.connect()
            batch = asyncio.create_task(link.send_many((line, None) for line in lines))
            await _wait_acked(link, 50)
            await link.cancel(end)
            with pytest.raises(StreamCancelled):
                await batch
            with pytest.raises(StreamCancelled):
                await link.send_many([("G1 X0", None)])

    with SimulatedPrinter(_slow_sim()) as sim:
        asyncio.run(run(sim))
        body = job_lines(sim.executed)
    assert body[-3:] == list(end)
    done = body[:-3]
    assert done == lines[:len(done)]
    assert 50 <= len(done) < len(lines)
