"""The station's names: one grammar for every aircraft, actuator, station, shard and group
name, whoever reads it (the intake's key check, the status reply's check, the metrics'
labels, the store, the configuration). A name is 1 to :data:`MAX_NAME_CHARS` letters,
digits, ``_``, ``.`` and ``-`` (docs/security.md, "Against an insider": the unit table is bounded per source).

The bound matters as much as the alphabet: a name the intake admits reaches every reader,
so each of them must accept every name the intake admits (issue 50: a 129-character actuator
name passed the intake and made the whole status reply malformed).
"""

from __future__ import annotations

import re

__all__ = ["MAX_NAME_CHARS", "NAME_PATTERN", "is_name", "name_problem", "is_unit"]

#: the longest name anywhere in the station [characters]
MAX_NAME_CHARS = 128

#: a name, as a regular expression without anchors (pydantic ``pattern``s anchor it)
NAME_PATTERN = rf"[A-Za-z0-9_.\-]{{1,{MAX_NAME_CHARS}}}"

_NAME = re.compile(NAME_PATTERN)


def is_name(v: object) -> bool:
    """Whether ``v`` is a name (a ``str`` of the grammar; the whole of it: no trailing
    newline, which ``^...$`` with ``re.match`` would let through)."""
    return isinstance(v, str) and _NAME.fullmatch(v) is not None


def name_problem(v: object) -> str | None:
    """Why ``v`` is not a name (one line, the value quoted and cut), or None."""
    if not isinstance(v, str):
        return f"not a string ({type(v).__name__})"
    if not v:
        return "empty"
    if len(v) > MAX_NAME_CHARS:
        return f"{len(v)} characters, more than {MAX_NAME_CHARS} ({v[:40]!r}...)"
    if _NAME.fullmatch(v) is None:
        return f"invalid name {v[:80]!r} (letters, digits, _ . - only)"
    return None


def is_unit(v: object) -> bool:
    """Whether ``v`` reads ``AIRCRAFT/ACTUATOR`` (two names)."""
    if not isinstance(v, str) or v.count("/") != 1:
        return False
    a, b = v.split("/")
    return is_name(a) and is_name(b)
