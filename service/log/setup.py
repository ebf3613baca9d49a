"""One log format for every servowatch process: the long-running ones (``run``, ``actuator``,
``router``, ``web``) write JSON lines on stderr by default, plain text with ``--plain-logs``,
and, under systemd, journald's native protocol with the record's fields as journal fields.
Every other command logs its warnings in the plain text form (journald under systemd,
:func:`setup_command_logging`), and the processes a command starts (the MCAP log process,
the warm-up's parts, replay and fleet-sim workers) log as their parent does
(:func:`inherit_logging`, from ``SERVOWATCH_CHILD_LOG``).

A record's structured fields come from ``extra={"fields": {...}}`` (an alarm: ``unit``,
``kind``, ``state``, ``value``, ``time``); every time is RFC 3339 UTC with milliseconds
(``service.log.retention.rfc3339``). JSON lines: ``{"time", "level", "logger", "msg",
...fields}``. Plain text: ``time LEVEL logger message``, the message's control characters
escaped so a quoted value cannot forge a line. journald (when ``JOURNAL_STREAM`` names this
process's stderr, as systemd sets it): ``MESSAGE``, ``PRIORITY``, ``SYSLOG_IDENTIFIER``,
``SERVOWATCH_LOGGER`` and ``SERVOWATCH_<FIELD>`` per field, so ``journalctl
SERVOWATCH_KIND=leak`` filters on them; a journal that cannot be reached falls back to JSON
lines on stderr.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import struct
import sys
from collections.abc import Mapping
from typing import IO, Any

from service.jsonutil import jsonable
from service.log.escape import CONTROLS
from service.log.retention import rfc3339

__all__ = [
    "JOURNAL_SOCKET",
    "JournalHandler",
    "JsonFormatter",
    "PlainFormatter",
    "add_log_arguments",
    "fields_of",
    "inherit_logging",
    "setup_command_logging",
    "setup_logging",
    "under_journal",
]

JOURNAL_SOCKET = "/run/systemd/journal/socket"
#: the variable a child process reads its parent's log format and level from (``json INFO``;
#: not ``SERVOWATCH_LOG_LEVEL``, which is the service config's ``log_level``)
ENV_CHILD = "SERVOWATCH_CHILD_LOG"
#: the keys of every record; a field named like one is written as ``field_<name>``
_RESERVED = frozenset({"time", "level", "logger", "msg", "exc"})
#: syslog priorities of the logging levels (journald's PRIORITY)
_PRIORITY = {"CRITICAL": 2, "ERROR": 3, "WARNING": 4, "INFO": 6, "DEBUG": 7}


def fields_of(record: logging.LogRecord) -> dict[str, Any]:
    """The record's structured fields (``extra={"fields": {...}}``) as plain JSON types."""
    f = getattr(record, "fields", None)
    return jsonable(dict(f)) if isinstance(f, Mapping) else {}


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time (RFC 3339), level, logger, msg, then the fields."""

    def format(self, record: logging.LogRecord) -> str:
        d: dict[str, Any] = {
            "time": rfc3339(record.created),
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        for k, v in fields_of(record).items():  # a field named like a key above: field_K
            d["field_" + str(k) if str(k) in _RESERVED else str(k)] = v
        if record.exc_info:
            d["exc"] = self.formatException(record.exc_info)
        return json.dumps(d, allow_nan=False, default=str)


class PlainFormatter(logging.Formatter):
    """``time LEVEL logger message``, one line per record (the time RFC 3339): the message's
    control characters escaped, so a quoted value (a key with a newline) cannot forge a
    line; a traceback follows as usual."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s %(message)s")

    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:  # noqa: N802
        return rfc3339(record.created)

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        esc = msg.translate(CONTROLS)
        if esc != msg:
            record = logging.makeLogRecord({**record.__dict__, "msg": esc, "args": None})
        return super().format(record)


def _journal_field(name: str, value: Any) -> bytes:
    """One field of journald's native protocol (the binary form when the value has a
    newline)."""
    v = value if isinstance(value, str) else json.dumps(value, default=str)
    b = v.encode("utf-8", "replace")
    key = name.encode()
    if b"\n" in b:
        return key + b"\n" + struct.pack("<Q", len(b)) + b + b"\n"
    return key + b"=" + b + b"\n"


def _field_name(k: str) -> str:
    """``SERVOWATCH_<K>``: journald field names are upper-case letters, digits and _."""
    name = "".join(c if c.isalnum() else "_" for c in str(k).upper())
    return "SERVOWATCH_" + name


class JournalHandler(logging.Handler):
    """Records to journald's native socket (``socket_path``), the fields as
    ``SERVOWATCH_*`` journal fields. A record the journal refuses goes to ``fallback``."""

    def __init__(
        self,
        socket_path: str = JOURNAL_SOCKET,
        identifier: str = "servowatch",
        fallback: logging.Handler | None = None,
    ) -> None:
        super().__init__()
        self.socket_path = socket_path
        self.identifier = identifier
        self.fallback = fallback
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)

    def payload(self, record: logging.LogRecord) -> bytes:
        msg = record.getMessage()
        if record.exc_info:
            msg += "\n" + logging.Formatter().formatException(record.exc_info)
        parts = [
            _journal_field("MESSAGE", msg),
            _journal_field("PRIORITY", str(_PRIORITY.get(record.levelname, 6))),
            _journal_field("SYSLOG_IDENTIFIER", self.identifier),
            _journal_field("SERVOWATCH_LOGGER", record.name),
            _journal_field("SERVOWATCH_TIME", rfc3339(record.created)),
        ]
        parts += [_journal_field(_field_name("field_" + k if k in _RESERVED else k), v)
                  for k, v in fields_of(record).items()]  # fmt: skip
        return b"".join(parts)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._sock.sendto(self.payload(record), self.socket_path)
        except OSError:
            if self.fallback is not None:
                self.fallback.handle(record)
        except Exception:
            self.handleError(record)

    def close(self) -> None:
        self._sock.close()
        super().close()


def under_journal(stream: IO | None = None, env: Mapping[str, str] | None = None) -> bool:
    """True when ``stream`` (stderr) is connected to the journal: ``JOURNAL_STREAM`` holds
    its ``device:inode`` (systemd.exec(5))."""
    env = os.environ if env is None else env
    want = env.get("JOURNAL_STREAM")
    if not want:
        return False
    try:
        st = os.fstat((stream or sys.stderr).fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return want == f"{st.st_dev}:{st.st_ino}"


def setup_logging(
    level: str | int = "INFO",
    structured: bool = True,
    *,
    stream: IO | None = None,
    env: Mapping[str, str] | None = None,
    journal_socket: str = JOURNAL_SOCKET,
) -> logging.Handler:
    """Root logging of a servowatch process: journald under systemd, else JSON lines on
    ``stream`` (stderr); plain text when not ``structured`` (``--plain-logs``). Returns the
    handler installed."""
    plain = not structured
    out = stream or sys.stderr
    h_stream = logging.StreamHandler(out)
    h_stream.setFormatter(PlainFormatter() if plain else JsonFormatter())
    h: logging.Handler = h_stream
    if not plain and under_journal(out, env):
        h = JournalHandler(journal_socket, fallback=h_stream)
    h._servowatch = True  # type: ignore[attr-defined]
    root = logging.getLogger()
    # replaces an earlier call's handler and a bare stderr one (logging.basicConfig's); a
    # capturing handler (pytest's caplog) stays
    root.handlers[:] = [h] + [
        x for x in root.handlers
        if not getattr(x, "_servowatch", False) and type(x) is not logging.StreamHandler
    ]  # fmt: skip
    root.setLevel(level)
    if stream is None and env is None:  # this process's stderr: its children log alike
        os.environ[ENV_CHILD] = f"{'plain' if plain else 'json'} {logging.getLevelName(root.level)}"
    return h


def add_log_arguments(p: Any) -> None:
    """``--plain-logs`` of the long-running commands."""
    p.add_argument("--plain-logs", action="store_true", help="plain-text logs, not JSON lines")


def setup_command_logging(level: str | int = "WARNING") -> logging.Handler:
    """Logging of a command that is not a service (``replay``, ``import``, ``fleet-sim``, ...):
    its warnings as plain text lines for the person who ran it, journald under systemd."""
    return setup_logging(level, structured=under_journal())


def inherit_logging() -> logging.Handler:
    """Logging of a child process: its parent's format and level (``SERVOWATCH_CHILD_LOG``,
    set by :func:`setup_logging`), else plain text at WARNING."""
    fmt, _, level = os.environ.get(ENV_CHILD, "plain WARNING").partition(" ")
    if level not in _PRIORITY:
        level = "WARNING"
    return setup_logging(level, structured=fmt == "json")
