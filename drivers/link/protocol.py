"""Marlin serial protocol: line framing, checksums, comment stripping and response parsing."""

from __future__ import annotations

from functools import reduce
from operator import xor

from drivers.link.responses import Response, parse_response

__all__ = ["Response", "checksum", "frame", "parse_response", "strip_comment"]


def xor_bytes(data: bytes) -> int:
    """XOR of every byte of ``data``, 0..255."""
    return reduce(xor, data, 0)


def checksum(text: str) -> int:
    """XOR of every byte of ``text`` (the part of a line before ``*``), 0..255."""
    return xor_bytes(text.encode("ascii", "replace"))


def frame(number: int, command: str) -> bytes:
    """One numbered, checksummed line as sent on the wire: ``N<n> <cmd>*<cs>\\n``."""
    body = f"N{number} {command}".encode("ascii", "replace")
    return b"%s*%d\n" % (body, reduce(xor, body, 0))


def strip_comment(line: str) -> str:
    """The command part of a G-code line: comments and surrounding blanks removed.

    Returns ``""`` for comment-only and blank lines, which are never sent.
    """
    command = line.split(";", 1)[0]
    if "(" in command:
        command = _strip_parenthesised(command)
    return command.strip()


def _strip_parenthesised(text: str) -> str:
    out: list[str] = []
    depth = 0
    for char in text:
        if char == "(":
            depth += 1
        elif char == ")" and depth:
            depth -= 1
        elif not depth:
            out.append(char)
    return "".join(out)
