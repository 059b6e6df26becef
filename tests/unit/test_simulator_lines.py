"""Marlin's line checks as a pure function: numbers, checksums, M110, comments."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from drivers.link.protocol import frame
from drivers.sim.lines import (
    ERR_CHECKSUM,
    ERR_LINE_NO,
    ERR_NO_CHECKSUM,
    check_line,
    strtol,
)


def _body(number: int, command: str) -> bytes:
    return frame(number, command).rstrip(b"\n")


def test_strtol_is_c_like():
    assert strtol(" 42abc") == 42
    assert strtol("-1") == -1
    assert strtol("x") == 0


def test_accepted_numbered_line():
    check = check_line(_body(8, "G1 X1 Y2"), 7)
    assert (check.error, check.command, check.number, check.last_n) == ("", "G1 X1 Y2", 8, 8)


def test_number_is_checked_before_checksum():
    assert check_line(b"N9 G1 X1*0", 7).error == ERR_LINE_NO
    assert check_line(b"N8 G1 X1*0", 7).error == ERR_CHECKSUM
    assert check_line(b"N8 G1 X1", 7).error == ERR_NO_CHECKSUM


def test_m110_skips_the_sequence_check_and_sets_the_last_line():
    assert check_line(_body(0, "M110 N0"), 500).last_n == 0
    assert check_line(_body(77, "M110"), 3).last_n == 77
    assert check_line(b"M110 N-1", 9).last_n == -1
    assert check_line(b"N1 M110 N5*0", 0).error == ERR_CHECKSUM


def test_unnumbered_comments_and_blanks():
    assert check_line(b"  G28 ; home", 4) == check_line(b"G28", 4)
    assert check_line(b"G28", 4).command == "G28"
    assert check_line(b"; only a comment", 4).command == ""
    assert check_line(b"   ", 4).command == ""


@given(
    number=st.integers(min_value=1, max_value=10**6),
    command=st.from_regex(r"[GM][0-9]{1,3}( [XYZEF]-?[0-9]{1,3}\.[0-9]{1,3}){0,4}",
                          fullmatch=True),
    index=st.integers(min_value=0),
    bit=st.integers(min_value=0, max_value=7),
)
def test_any_single_bit_flip_of_a_framed_line_is_caught(number, command, index, bit):
    line = bytearray(_body(number, command))
    index %= len(line)
    line[index] ^= 1 << bit
    check = check_line(bytes(line), number - 1)
    if check.number is None:  # the N itself was hit: garbage, answered "Unknown command"
        assert check.command[:1] not in ("G", "M", "T")
    else:  # never a changed command accepted (a hit checksum may still read the same)
        assert check.error or check.command == command
