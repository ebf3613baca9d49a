"""Reading servowatch's log lines in tests (``service.log.setup``): JSON lines with an RFC 3339
``time``, or with ``--plain-logs`` ``TIME LEVEL LOGGER MESSAGE``; a service's facts (the page's
``url``, the router's ``listen``) are fields of its records."""

from __future__ import annotations

import json
import re
from datetime import datetime
from pathlib import Path
from typing import Any

#: RFC 3339 UTC with milliseconds, as ``service.log.retention.rfc3339`` writes it
RFC3339 = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$")
#: a plain-text line: time, level, logger, message
PLAIN = re.compile(r"^(\S+) (DEBUG|INFO|WARNING|ERROR|CRITICAL) (\S+) (.*)$")


def is_time(text: str) -> bool:
    """An RFC 3339 time (the format's, and one ``datetime.fromisoformat`` reads)."""
    if not RFC3339.match(text):
        return False
    datetime.fromisoformat(text.replace("Z", "+00:00"))
    return True


def records(text: str) -> list[dict[str, Any]]:
    """The JSON records among ``text``'s lines (other lines, e.g. Zenoh's own trace, skipped)."""
    out = []
    for line in text.splitlines():
        if line.startswith("{"):
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return out


def find(text: str, logger: str, field: str) -> dict[str, Any] | None:
    """The first record of ``logger`` that has ``field``."""
    return next((r for r in records(text) if r.get("logger") == logger and field in r), None)


def find_in(path: Path, logger: str, field: str) -> dict[str, Any] | None:
    return find(path.read_text() if path.exists() else "", logger, field)


def check_json_lines(text: str) -> list[dict[str, Any]]:
    """Every line of ``text`` parsed as one JSON record with an RFC 3339 ``time``, a level, a
    logger and a message (AssertionError naming the first line that is not)."""
    out = []
    for line in text.splitlines():
        try:
            r = json.loads(line)
        except json.JSONDecodeError:
            raise AssertionError(f"not a JSON log line: {line!r}") from None
        assert isinstance(r, dict) and {"time", "level", "logger", "msg"} <= r.keys(), line
        assert is_time(r["time"]), line
        out.append(r)
    return out


def check_plain_lines(text: str) -> list[tuple[str, str, str, str]]:
    """Every line of ``text`` as ``TIME LEVEL LOGGER MESSAGE`` with an RFC 3339 time."""
    out = []
    for line in text.splitlines():
        m = PLAIN.match(line)
        assert m and is_time(m.group(1)), f"not a plain log line: {line!r}"
        out.append(m.groups())
    return out
