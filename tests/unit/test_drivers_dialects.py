"""Firmware the link was not written against, on the virtual clock: each dialect's refusals
answered from what the printer said, never by waiting out a silence.

The scripted tests feed the core a firmware's answers line by line with no tick (a tick is
the only way time alone makes the link act): the link must work out the next line from the
answers alone. The runs stream to the virtual Marlin in each dialect of
``drivers.sim.config.DIALECTS`` with its seeded fault, at the default ``probe_after_s`` (5 s),
so a stall shows as a gap between writes.
"""

from __future__ import annotations

import pytest
from support.linkcores import connected_core
from support.linkrun import run_core, run_send_and_wait

from drivers.link.config import StreamerConfig
from drivers.link.core import LinkCore
from drivers.link.events import Acked
from drivers.link.protocol import frame
from drivers.sim.config import DIALECTS, dialect
from drivers.sim.lines import ERR_CHECKSUM, ERR_LINE_NO

# the link's defaults (5 s before a probe after silence), without temperature polls
LINK = StreamerConfig(temperature_interval_s=0, resync_quiet_s=0.01)
PROBE_ANSWER = "ok T:20.00 /0.00 B:20.00 /0.00 @:0 B@:0"
MAX_GAP_S = 0.5


def _writes(core: LinkCore, now: float) -> list[tuple[int, str]]:
    """Every line the core writes now: (number, command)."""
    out = []
    while (data := core.next_bytes(now)) is not None:
        head, rest = data.decode().split(" ", 1)
        out.append((int(head[1:]), rest.rsplit("*", 1)[0]))
    return out


def _jobs(core: LinkCore, count: int) -> None:
    for i in range(count):
        core.queue_job(f"G1 X{i}.5 Y{i}", 10 + i)


def test_a_request_for_the_next_line_not_yet_sent_goes_on_without_a_silence():
    # an emulation (OctoPrint's virtual printer) refuses the next line before it is sent:
    # it takes line L, says "checksum mismatch, Last Line: L", "Resend: L+1", "ok", and
    # that ok is the only one L gets. Each such L stayed in the window for good, until a
    # full window waited 5 s for a probe (27 lines/s where a send-and-wait host did 372)
    core = connected_core(LINK)
    _jobs(core, 40)
    t = 0.01
    taken: list[int] = []  # lines the printer took, in order
    for round_ in range(6):
        written = _writes(core, t)
        assert written, f"nothing written in round {round_}: the link waits for a silence"
        for number, command in written:
            t += 0.001
            taken.append(number)
            if command == "M105":
                core.feed(PROBE_ANSWER, t)
            elif number == written[-1][0] and command != "M105":
                # the last line written is taken, and the next one asked for
                core.feed(f"Error:{ERR_CHECKSUM}{number}", t)
                core.feed(f"Resend: {number + 1}", t)
                core.feed("ok", t)
            else:
                core.feed("ok", t)
    # every line the printer took is acknowledged: no ok was waited for in vain
    for _ in range(3):
        for number, command in _writes(core, t):
            t += 0.001
            taken.append(number)
            core.feed(PROBE_ANSWER if command == "M105" else "ok", t)
    assert taken == sorted(set(taken))  # each line once, in order
    assert core.acks.last_acked_number == taken[-1]
    assert len(core.window) == 0
    assert core.stats.probes == 0  # no probe after silence: none was needed


def test_a_copy_of_a_line_the_printer_took_dropped_without_an_ok_ends_no_stream():
    # Marlin drops a line numbered as the last one it took (or one below) silently: no
    # ok, no error. Lines 1-3 were taken and acknowledged; a refusal naming 1 as the
    # last line comes late (noise made it, or it was on its way): the link takes 2 and 3
    # back and replays them, and the printer answers their copies with nothing. The
    # window then waited for those oks until a probe after 5 s of silence
    core = connected_core(LINK)
    _jobs(core, 10)
    t = 0.01
    assert [n for n, _ in _writes(core, t)] == [1, 2, 3, 4]
    acked = [e.number for c in ("ok",) * 3 for e in core.feed(c, t) if isinstance(e, Acked)]
    assert acked == [1, 2, 3]
    t += 0.001
    core.feed(f"Error:{ERR_CHECKSUM}1", t)  # late: the printer has 4 by now
    core.feed("Resend: 2", t)
    core.feed("ok", t)
    core.feed("ok", t)  # line 4's
    last_n = 4
    for _ in range(8):
        written = _writes(core, t)
        for number, command in written:
            t += 0.001
            if last_n - 1 <= number <= last_n:
                continue  # a duplicate: dropped without a word
            if number != last_n + 1:
                core.feed(f"Error:{ERR_LINE_NO}{last_n}", t)
                core.feed(f"Resend: {last_n + 1}", t)
                core.feed("ok", t)
                break
            last_n = number
            core.feed(PROBE_ANSWER if command == "M105" else "ok", t)
    # every job line went through on the printer's answers alone, no tick
    assert not core.writer.pending
    assert core.acks.last_acked_number == last_n == core.next_number - 1
    assert len(core.window) == 0


@pytest.mark.parametrize("name", sorted(DIALECTS))
@pytest.mark.parametrize("p", [0.02, 0.10])
def test_every_dialect_streams_exactly_once_without_a_stall(name, p):
    # 2 and 10 % of lines refused (or a tenth of that in resets, for the M110 dialects),
    # at the link's own 5 s probe interval: a stall shows as a gap between writes
    lines = [f"G1 X{100 + i % 50}.{i % 7} Y{100 + i // 50}.5 E0.0{i % 9}" for i in range(1500)]
    fault = DIALECTS[name][1]
    p = p / 10 if fault == "reset" else p
    sim = dialect(name, p, baud=250000, latency_s=0.001, seed=12, keepalive_s=0.05,
                  boot_delay_s=0.05)
    run = run_core(lines, sim, LINK, max_seconds=3000)
    assert run.executed == lines
    assert run.acked == lines
    assert run.printer.faults.fired[fault] >= 1500 * p / 3
    assert run.max_gap < MAX_GAP_S, f"{name}: a {run.max_gap:.2f} s gap between writes"
    wait = run_send_and_wait(lines, sim, max_seconds=3000)
    assert wait.executed == lines
    assert run.rate >= wait.rate


def test_the_handshake_numbers_the_m110_as_the_value_it_sets():
    # "N1 M110 N0": Marlin takes the parameter (last line 0), an emulation the line's own
    # number (last line 1); the next line, N1, was then refused by the emulation. Numbered
    # as the value it sets, both readings agree
    core = LinkCore(LINK)
    core.begin_connect(0.0)
    core.feed("start", 0.0)
    assert core.next_bytes(0.0) == b"\n"  # the end of any noise the printer holds
    assert core.next_bytes(0.0) == frame(0, "M110 N0")
    assert core.next_bytes(0.0) is None  # nothing after it until its ok
    core.feed("ok", 0.001)
    assert core.next_bytes(0.001) == frame(1, "M115")


@pytest.mark.parametrize("withheld", [False, True])
def test_a_probe_answer_after_a_held_probe_acknowledges_no_job_line_before_its_ok(withheld):
    # Two probes out (1, 2); the printer takes 2 with a refusal naming it its last line
    # ("Last Line: 2", "Resend: 3", "ok"), so 2's answer may or may not come; probe 3
    # follows a silence. The first answer (1's) is taken for 3, every probe before it
    # done: the answers of 1 and 2 are then still owed, not only the held one's. Owing
    # one, 2's answer was later taken for the probe after three job lines (7), which
    # acknowledged lines 4-6 before the printer ran them, and a reset then renumbered
    # past them: acknowledged, never run
    core = connected_core(LINK)
    t = 0.01
    core.queue_control("M105", internal=True, probe=True)
    core.queue_control("M105", internal=True, probe=True)
    assert _writes(core, t) == [(1, "M105"), (2, "M105")]
    for text in (f"Error:{ERR_CHECKSUM}2", "Resend: 3", "ok"):
        core.feed(text, t)
    t = 0.11
    core.tick(t)
    assert _writes(core, t) == [(3, "M105")]
    core.feed(PROBE_ANSWER, t)  # 1's answer
    if not withheld:
        core.feed(PROBE_ANSWER, t)  # 2's: this firmware answers a held probe too
    _jobs(core, 3)
    assert [n for n, _ in _writes(core, t)] == [4, 5, 6]
    core.queue_control("M105", internal=True, probe=True)
    assert _writes(core, t) == [(7, "M105")]
    acked = [e.number for e in core.feed(PROBE_ANSWER, t) if isinstance(e, Acked)]  # 3's
    assert acked == []  # lines 4-6 have not run yet
    if withheld:
        # their own oks acknowledge them, one each, and 7's answer the probe
        for number in (4, 5, 6):
            acked = [e.number for e in core.feed("ok", t) if isinstance(e, Acked)]
            assert acked == [number]
        core.feed(PROBE_ANSWER, t)
        assert core.acks.last_acked_number == 7
        assert len(core.window) == 0
        return
    # the board resets before running 4: they are written again after the M110
    core.feed("start", t)
    t += 0.1  # booted
    assert _writes(core, t) == [(3, "M110 N3")]
    core.feed("ok", t)
    assert [n for n, _ in _writes(core, t)][:3] == [4, 5, 6]


def _keeping_emulation(core: LinkCore, refuse: set[int], rounds: int,
                       own_ok: frozenset[int] = frozenset()) -> tuple[list[str], list[int]]:
    """Stream to a scripted firmware that keeps its receive buffer after a refusal, as
    OctoPrint's virtual printer does: everything the core writes in a round is on the wire
    before the first answer is read. A line numbered in ``refuse`` is taken and the next
    one asked for (its ``ok`` the only one it gets); a line numbered as one already taken
    is refused as out of order; one in ``own_ok`` too, but it gets an ``ok`` of its own
    after the refusal's, as Marlin answers a line it read. Returns the commands taken, in
    order, and the number of every line written."""
    last = 0
    taken: list[str] = []
    written_numbers: list[int] = []
    t = 0.01
    for _ in range(rounds):
        written = _writes(core, t)
        answers: list[str] = []
        for number, command in written:
            written_numbers.append(number)
            if number != last + 1:
                answers += [f"Error:{ERR_LINE_NO}{last}", f"Resend: {last + 1}", "ok"]
                continue
            last = number
            taken.append(command)
            if number in refuse:
                answers += [f"Error:{ERR_CHECKSUM}{number}", f"Resend: {number + 1}", "ok"]
                if number in own_ok:
                    answers.append("ok")
            else:
                answers.append(PROBE_ANSWER if command == "M105" else "ok")
        for answer in answers:
            t += 0.001
            core.feed(answer, t)
    return taken, written_numbers


def test_a_firmware_seen_to_keep_the_lines_behind_a_refusal_gets_no_copies_of_them():
    # a refusal naming a line in flight as the last one read, with lines behind it in
    # flight too: Marlin drains those (they are replayed), this firmware takes them, so
    # their copies are each refused as duplicates. The first time shows it (a copy
    # refused with a Last Line past it); from then on the lines in flight are left to it
    core = connected_core(LINK)
    _jobs(core, 60)
    taken, numbers = _keeping_emulation(core, {5, 25, 45}, rounds=40)
    jobs = [c for c in taken if c != "M105"]
    assert jobs == [f"G1 X{i}.5 Y{i}" for i in range(60)]  # each once, in order
    assert core.model.keeps_buffer
    assert core.stats.replays_skipped == 2
    first_copy_free = numbers.index(26)  # written before the second refusal was read
    later = numbers[first_copy_free:]
    assert len(later) == len(set(later))  # no line written twice after the lesson
    assert len(core.window) == 0


def test_a_learned_stand_in_ok_spares_the_probe_after_most_refusals():
    # OctoPrint's virtual printer takes the refused line by number and answers it with
    # nothing but the ok after its Resend: once two probes showed that, the ok is counted
    # for the line and no probe is asked, but for one refusal in four, still checked
    core = connected_core(LINK)
    _jobs(core, 200)
    refuse = set(range(5, 200, 10))
    taken, numbers = _keeping_emulation(core, refuse, rounds=200)
    assert [c for c in taken if c != "M105"] == [f"G1 X{i}.5 Y{i}" for i in range(200)]
    assert core.model.stands_in
    counted = core.stats.stand_ins_counted
    assert counted >= 10
    assert taken.count("M105") <= len(refuse) - counted
    later = numbers[numbers.index(20):]
    assert len(later) == len(set(later))  # copies only before the buffer was learned
    assert len(core.window) == 0
    assert core.acks.last_acked_number == numbers[-1]


def test_a_firmware_seen_to_answer_a_released_line_itself_is_never_trusted_again():
    # a firmware that keeps its buffer, where one refusal's line gets its own ok after
    # the Resend's: counted for it, that ok would have put the count a line ahead of the
    # printer. After that, every such refusal is probed, whatever the later ones show
    core = connected_core(LINK)
    _jobs(core, 120)
    refuse = set(range(5, 120, 10))
    taken, _numbers = _keeping_emulation(core, refuse, rounds=200, own_ok=frozenset({25}))
    assert [c for c in taken if c != "M105"] == [f"G1 X{i}.5 Y{i}" for i in range(120)]
    assert not core.model.stands_in
    assert core.model.stand_ins_seen == -1
    assert core.stats.stand_ins_counted == 0
    assert taken.count("M105") >= len(refuse) - 1
    assert len(core.window) == 0


def test_a_firmware_that_drains_after_a_refusal_unlearns_a_kept_buffer():
    # learned on a keeping firmware, the link skips the replay; a firmware that drained
    # the lines after all refuses the next one asking for the same line: replayed then,
    # and replayed at once after every later refusal
    core = connected_core(LINK)
    core.model.learn_keeps_buffer(True)
    _jobs(core, 8)
    t = 0.01
    written = _writes(core, t)
    assert [n for n, _ in written][:3] == [1, 2, 3]
    core.feed("ok", t)  # line 1
    core.feed(f"Error:{ERR_CHECKSUM}2", t)  # 2 taken, 3 asked for: the rest drained
    core.feed("Resend: 3", t)
    core.feed("ok", t)
    assert core.stats.replays_skipped == 1
    core.feed(f"Error:{ERR_LINE_NO}2", t)  # the probe, or a line behind, refused
    core.feed("Resend: 3", t)
    core.feed("ok", t)
    assert not core.model.keeps_buffer
    again = [n for n, c in _writes(core, t + 0.001) if c != "M105"]
    assert again[:1] == [3]
