"""Marlin line framing: comments out, `N<n> <cmd>*<xor>` in."""

from __future__ import annotations

import re

__all__ = [
    "checksum",
    "clean_line",
    "format_line",
    "has_own_number",
    "parse_framed_line",
]


def checksum(text: str) -> int:
    """XOR of every byte of *text* (everything before the `*`)."""
    value = 0
    for byte in text.encode("ascii", "replace"):
        value ^= byte
    return value


#: A command that starts with a line number of its own (`N7 ...`).
_OWN_NUMBER = re.compile(r"[Nn]\s*\d")


def has_own_number(text: str) -> bool:
    """*text* starts with a line number of its own: framed again (`N1 N7 ...`),
    Marlin would take its N as the next line number, or its command as unknown."""
    return text[:1] in ("N", "n") and _OWN_NUMBER.match(text) is not None


def format_line(n: int, command: str) -> str:
    """Frame *command* with line number *n* and checksum, without the newline."""
    body = f"N{n} {command}"
    return f"{body}*{checksum(body)}"


def clean_line(raw: str) -> str:
    """The command part of a G-code line: comments and outer whitespace removed.

    `;` starts a comment to the end of the line; `(...)` is a comment too (GRBL and
    RS274). Returns "" for a line that holds nothing to send.
    """
    line = raw.split(";", 1)[0]
    if "(" in line:
        out = []
        depth = 0
        for char in line:
            if char == "(":
                depth += 1
            elif char == ")" and depth:
                depth -= 1
            elif not depth:
                out.append(char)
        line = "".join(out)
    return line.strip()


def parse_framed_line(line: str) -> tuple[int | None, str, bool]:
    """Split a received line into (line number, command, checksum ok).

    This is the firmware's side of framing, used by the simulators and by tests.
    A line without `N` has no number and is always "ok"; a line with `N` but no
    `*` is not ok (Marlin: "No Checksum with line number").
    """
    stripped = line.strip()
    if not stripped.startswith("N"):
        return None, stripped, True
    star = stripped.rfind("*")
    if star < 0:
        return _line_number(stripped), _after_number(stripped), False
    body, _, tail = stripped[:star], "*", stripped[star + 1 :]
    try:
        good = int(tail) == checksum(body)
    except ValueError:
        good = False
    return _line_number(body), _after_number(body), good


def _line_number(body: str) -> int | None:
    digits = ""
    for char in body[1:]:
        if char.isdigit() or (char == "-" and not digits):
            digits += char
        else:
            break
    try:
        return int(digits)
    except ValueError:
        return None


def _after_number(body: str) -> str:
    index = 1
    while index < len(body) and (body[index].isdigit() or body[index] == "-"):
        index += 1
    return body[index:].strip()
