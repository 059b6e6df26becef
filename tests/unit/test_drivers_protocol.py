"""Framing, response parsing (table and property-based), resend sanity checks, the window."""

from __future__ import annotations

import string

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.link.protocol import checksum, frame, parse_response, strip_comment
from drivers.link.resend import edit_distance, recover, resolve_resend
from drivers.link.window import InFlight, SendWindow

KINDS = {"ok", "resend", "busy", "error", "temperature", "start", "wait", "capability", "echo",
         "other"}


def test_frame_is_number_command_and_xor_checksum():
    body = "N1 G1 X10"
    expected = 0
    for byte in body.encode():
        expected ^= byte
    assert frame(1, "G1 X10") == f"{body}*{expected}\n".encode()
    assert frame(0, "M110 N0") == b"N0 M110 N0*125\n"  # the value hosts commonly log
    assert checksum("") == 0


def test_strip_comment_keeps_only_the_command():
    assert strip_comment("G1 X1 ; move") == "G1 X1"
    assert strip_comment("; only a comment") == ""
    assert strip_comment("G1 (inline) X2") == "G1  X2"
    assert strip_comment("   ") == ""


@pytest.mark.parametrize(
    ("line", "kind", "fields"),
    [
        ("ok", "ok", {}),
        ("ok N12 P15 B3", "ok", {"line": 12, "planner_free": 15, "queue_free": 3}),
        ("Resend: 42", "resend", {"line": 42, "digits": "42"}),
        ("Resend:42", "resend", {"line": 42}),
        ("rs 17", "resend", {"line": 17}),
        ("rs N17", "resend", {"line": 17}),
        ("Resend: 034497", "resend", {"line": 34497, "digits": "034497"}),
        ("Error:checksum mismatch, Last Line: 41", "error",
         {"error_kind": "checksum", "line": 41}),
        ("Error:Line Number is not Last Line Number+1, Last Line: 5", "error",
         {"error_kind": "line_number", "line": 5}),
        ("Error:No Checksum with line number, Last Line: 9", "error",
         {"error_kind": "no_checksum", "line": 9}),
        ("Error:No Line Number with checksum, Last Line: 9", "error",
         {"error_kind": "no_line_number", "line": 9}),
        ("Error:Printer halted. kill() called!", "error", {"error_kind": "halted"}),
        ("Error:Printer stopped due to errors. Fix the error and use M999 to restart.",
         "error", {"error_kind": "stopped"}),
        ("Error:MAXTEMP triggered", "error", {"error_kind": "other"}),
        ("!! Move out of range", "error", {"error_kind": "other"}),
        ("echo:busy: processing", "busy", {"text": "processing"}),
        ("echo:busy: paused for user", "busy", {"text": "paused for user"}),
        ("wait", "wait", {}),
        ("start", "start", {}),
        ("Cap:EMERGENCY_PARSER:1", "capability", {"name": "EMERGENCY_PARSER", "value": "1"}),
        ("echo:Unknown command: \"G999\"", "echo", {"text": "Unknown command: \"G999\""}),
        ("", "other", {}),
        ("okay then", "other", {}),
    ],
)
def test_marlin_lines_are_classified(line, kind, fields):
    response = parse_response(line + "\r\n")
    assert response.kind == kind
    for name, value in fields.items():
        assert getattr(response, name) == value


@pytest.mark.parametrize(
    ("line", "temps", "power"),
    [
        ("ok T:201.2 /202.0 B:60.1 /60.0 @:64 B@:127",
         {"T": (201.2, 202.0), "B": (60.1, 60.0)}, {"@": 64, "B@": 127}),
        (" T:25.00 /0.00 B:24.00 /0.00 @:0 B@:0", {"T": (25.0, 0.0), "B": (24.0, 0.0)},
         {"@": 0, "B@": 0}),
        ("T:201.2 /202.0 B:60.1 /60.0", {"T": (201.2, 202.0), "B": (60.1, 60.0)}, {}),
        ("T0:200.0 /200.0 T1:30.0 /0.0 B:60.0 /60.0 T:200.0 /200.0 @:0 B@:0 @0:10 @1:0",
         {"T0": (200.0, 200.0), "T1": (30.0, 0.0), "B": (60.0, 60.0), "T": (200.0, 200.0)},
         {"@": 0, "B@": 0, "@0": 10, "@1": 0}),
        ("T:201.2 E:0 W:?", {"T": (201.2, None)}, {}),
        ("T:180.5 /210.0 B:59.9 /60.0 @:127 B@:0 W:3", {"T": (180.5, 210.0),
                                                        "B": (59.9, 60.0)},
         {"@": 127, "B@": 0}),
    ],
)
def test_temperature_reports_in_common_shapes(line, temps, power):
    response = parse_response(line)
    assert response.kind == ("ok" if line.startswith("ok") else "temperature")
    assert response.temperatures == temps
    assert response.power == power


def test_firmware_banner_is_a_capability_line():
    response = parse_response("FIRMWARE_NAME:Marlin 2.1.2 PROTOCOL_VERSION:1.0 EXTRUDER_COUNT:1")
    assert response.kind == "capability"
    assert response.name == "FIRMWARE_NAME"
    assert response.value.startswith("Marlin 2.1.2")


# -- property-based ------------------------------------------------------------------------

_temps = st.floats(min_value=-20, max_value=400, allow_nan=False).map(lambda v: round(v, 2))


@st.composite
def responses(draw):
    """(line, kind, check) for a generated well-formed Marlin response."""
    choice = draw(st.sampled_from(["ok", "adv", "resend", "rs", "error", "busy", "temp",
                                   "cap", "start", "wait"]))
    n = draw(st.integers(min_value=0, max_value=10_000_000))
    if choice == "ok":
        return "ok", "ok", lambda r: r.line is None
    if choice == "adv":
        p, b = draw(st.integers(0, 64)), draw(st.integers(0, 32))
        return f"ok N{n} P{p} B{b}", "ok", lambda r: (r.line, r.planner_free,
                                                       r.queue_free) == (n, p, b)
    if choice == "resend":
        return f"Resend: {n}", "resend", lambda r: r.line == n
    if choice == "rs":
        return f"rs {n}", "resend", lambda r: r.line == n
    if choice == "error":
        text = draw(st.sampled_from(["checksum mismatch", "Line Number is not Last Line Number+1",
                                     "No Checksum with line number"]))
        return f"Error:{text}, Last Line: {n}", "error", lambda r: r.line == n
    if choice == "busy":
        return "echo:busy: processing", "busy", lambda r: r.text == "processing"
    if choice == "temp":
        t, tt, b, bt = (draw(_temps) for _ in range(4))
        prefix = draw(st.sampled_from(["ok ", " ", ""]))
        line = f"{prefix}T:{t} /{tt} B:{b} /{bt} @:0 B@:0"
        kind = "ok" if prefix == "ok " else "temperature"
        return line, kind, lambda r: r.temperatures == {"T": (t, tt), "B": (b, bt)}
    if choice == "cap":
        name = draw(st.text(string.ascii_uppercase + "_", min_size=1, max_size=24))
        value = draw(st.sampled_from(["0", "1"]))
        return f"Cap:{name}:{value}", "capability", lambda r: (r.name, r.value) == (name, value)
    return choice, choice, lambda r: True


@settings(max_examples=400, deadline=None)
@given(responses())
def test_generated_responses_are_classified_with_their_fields(case):
    line, kind, check = case
    response = parse_response(line)
    assert response.kind == kind
    assert check(response)


@settings(max_examples=400, deadline=None)
@given(responses(), st.data())
def test_mangled_responses_never_raise(case, data):
    line, _, _ = case
    raw = bytearray(line.encode())
    for _ in range(data.draw(st.integers(1, 3))):
        if not raw:
            break
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= 1 << data.draw(st.integers(0, 7))
    response = recover(parse_response(raw.decode("latin-1")))
    assert response.kind in KINDS
    if response.kind == "resend":
        assert response.line is not None
        assert response.line >= 0


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=120))
def test_arbitrary_text_never_raises(text):
    assert parse_response(text).kind in KINDS


# -- resend sanity ---------------------------------------------------------------------------

def test_resend_with_lost_digit_maps_to_the_line_in_flight():
    window = range(134495, 134501)
    assert resolve_resend("034497", window) == 134497
    assert resolve_resend("13449", window) is None or resolve_resend("13449", window) in window


def test_resend_for_a_line_not_sent_is_refused():
    assert resolve_resend("999999", range(100, 105)) is None


def test_resend_exact_and_confirmed_by_last_line():
    assert resolve_resend("102", range(100, 105)) == 102
    # the error said Last Line 100 and the request names another plausible line: one of
    # them was garbled, and neither is obeyed (the next refusal says which)
    assert resolve_resend("103", range(100, 105), error_last_line=100) is None
    assert resolve_resend("100", range(100, 105), error_last_line=100) is None
    # the request garbled to a line that cannot be asked for: the error's Last Line decides
    assert resolve_resend("999", range(100, 105), error_last_line=100) == 101
    # a Last Line outside the window does not override a plausible request
    assert resolve_resend("103", range(100, 105), error_last_line=5) == 103


def test_a_request_its_error_confirms_is_never_repaired_into_another_line():
    # "Last Line: 0" and "Resend: 1" agree: the printer lost its numbering. Read as "41"
    # with a digit lost, the link replayed 41, refused the same way, for ever
    assert resolve_resend("1", range(40, 44), error_last_line=0) is None
    assert resolve_resend("1", range(40, 44)) == 41  # without the error, a digit lost


def test_ambiguous_repair_is_refused():
    assert resolve_resend("1", range(10, 20)) is None


def test_edit_distance():
    assert edit_distance("034497", "134497") == 1
    assert edit_distance("", "abc") == 3
    assert edit_distance("kitten", "sitting") == 3


def test_recover_garbled_replies():
    assert recover(parse_response("oj")).kind == "ok"
    # a probe's answer with the space after "ok" changed still answers the probe
    probe = recover(parse_response("ok!T:20.00 /0.00 B:20.00 /0.00 @:0 B@:0"))
    assert probe.kind == "ok"
    assert probe.has_temperatures
    assert recover(parse_response("oj T:20.00 /0.00 B:20.00 /0.00")).has_temperatures
    assert recover(parse_response("Resgnd: 12")).line == 12
    assert recover(parse_response("Erbor:checksum mismatch, Last Line: 7")).error_kind == "checksum"
    assert recover(parse_response("stavt")).kind == "start"
    assert recover(parse_response("hello")).kind == "other"


@pytest.mark.parametrize(("garbled", "kind"), [
    ("Error:Line Numbes is not Last Line Number+1, Last Line: 39", "line_number"),
    ("Error:checksum mismatah, Last Line: 7", "checksum"),
    ("Error:No Checksum with lijne number, Last Line: 7", "no_checksum"),
    ("Error:No Line Number with checksup, Last Line: 7", "no_line_number"),
])
def test_a_garbled_line_error_message_is_still_a_line_error(garbled, kind):
    # otherwise the Resend after it looks unannounced and its ok counts for a line
    response = recover(parse_response(garbled))
    assert response.error_kind == kind
    assert response.line == int(garbled.rsplit(" ", 1)[1])


def test_other_errors_are_left_as_they_are():
    response = recover(parse_response("Error:MINTEMP triggered, system stopped! Heater_ID: 0"))
    assert response.error_kind == "stopped"
    assert recover(parse_response("Error:Heating failed")).error_kind == "other"


# -- window ----------------------------------------------------------------------------------

def test_window_bounds_bytes_and_lines():
    window = SendWindow(max_bytes=100, max_lines=3)
    assert window.has_room(500)  # an empty window always takes one line
    window.push(InFlight(1, "G1", 40))
    window.push(InFlight(2, "G1", 40))
    assert not window.has_room(30)
    assert window.has_room(20)
    window.push(InFlight(3, "G1", 10))
    assert not window.has_room(1)  # three commands
    assert [e.number for e in window.ack_one()] == [1]
    assert window.bytes_in_flight == 50


def test_window_probe_acknowledges_everything_before_it():
    window = SendWindow(127, 8)
    for n in range(1, 4):
        window.push(InFlight(n, "G1", 10))
    window.push(InFlight(4, "M105", 10, internal=True, probe=True))
    window.push(InFlight(5, "G1", 10))
    assert [e.number for e in window.ack_probe()] == [1, 2, 3, 4]
    assert window.numbers() == [5]


def test_window_late_probe_answer_never_takes_job_lines_sent_after_it():
    # probe 1's answer is slow; probe 4 goes out; probe 1's answer is probe 1's alone
    window = SendWindow(127, 8)
    window.push(InFlight(1, "M105", 10, internal=True, probe=True))
    window.push(InFlight(2, "G1", 10))
    window.push(InFlight(3, "G1", 10))
    window.push(InFlight(4, "M105", 10, internal=True, probe=True))
    assert [e.number for e in window.ack_probe()] == [1]
    assert [e.number for e in window.ack_one()] == [2]
    assert [e.number for e in window.ack_one()] == [3]
    assert [e.number for e in window.ack_probe()] == [4]
    assert window.ack_probe() == []  # an answer matching no M105 takes nothing


def test_window_lost_probe_answer_is_shifted_out_then_the_next_probe_resyncs():
    # probe 1's answer is lost: the oks of 2 and 3 shift it out, probe 4 ends exact
    window = SendWindow(127, 8)
    window.push(InFlight(1, "M105", 10, internal=True, probe=True))
    window.push(InFlight(2, "G1", 10))
    window.push(InFlight(3, "G1", 10))
    window.push(InFlight(4, "M105", 10, internal=True, probe=True))
    window.push(InFlight(5, "G1", 10))
    assert [e.number for e in window.ack_one()] == [1]  # ok of 2
    assert [e.number for e in window.ack_one()] == [2]  # ok of 3
    assert [e.number for e in window.ack_probe()] == [3, 4]
    assert window.numbers() == [5]


def test_window_of_stale_probes_resyncs_on_one_answer():
    # every probe answered but the answers miscounted: one answer clears the run of
    # probes (internal lines only), never the job line behind it
    window = SendWindow(127, 8)
    for n in range(1, 5):
        window.push(InFlight(n, "M105", 10, internal=True, probe=True))
    window.push(InFlight(5, "G1", 10))
    assert [e.number for e in window.ack_probe()] == [1, 2, 3, 4]
    assert window.ack_probe() == []
    # a job's own M105 is answered by its ok T: and stops the run
    window.push(InFlight(6, "M105", 10))
    window.push(InFlight(7, "M105", 10))
    assert [e.number for e in window.ack_probe()] == [5, 6]
    assert window.numbers() == [7]


def test_window_ack_upto_takes_the_line_and_stale_copies_but_keeps_later_lines():
    window = SendWindow(127, 8)
    for number, copy in [(5, True), (7, False), (6, True), (4, True), (8, False)]:
        window.push(InFlight(number, f"G1 X{number}", 10, copy=copy))
    assert [e.number for e in window.ack_upto(6)] == [5, 6, 4]
    assert window.numbers() == [7, 8]
    assert window.bytes_in_flight == 20
    assert [e.number for e in window.ack_upto(7)] == [7]  # the usual case: the head alone
    assert window.ack_upto(7) == []
    assert window.numbers() == [8]


def test_window_drop_from_and_ack_through():
    window = SendWindow(127, 8)
    for n in range(1, 6):
        window.push(InFlight(n, "G1", 10))
    assert [e.number for e in window.drop_from(4)] == [4, 5]
    assert [e.number for e in window.ack_through(2)] == [1, 2]
    assert window.ack_through(99) == []
    assert window.numbers() == [3]
