"""An ``McapLogger`` in a child process: row encoding, compression and MCAP writing on another
core.

The daemon (and a replay with ``--out``) hand it whole blocks once per tick: the accepted
measurements and the outputs as the numpy arrays the daemon already decoded (pickled through
the pipe; the child decodes nothing). The child writes them with ``McapLogger.log_block``; if
the parent dies, the child sees its pipe close and finishes the file.
"""

from __future__ import annotations

import contextlib
import json
import logging
import socket
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from models.channels import SENSORS

__all__ = ["ProcessLogger", "MEAS_LOG_FIELDS"]

#: fields of a logged measurement, in the key order of ``messages.decode_meas_dicts``: the
#: channels (NaN: absent), seq and t
MEAS_LOG_FIELDS: tuple[str, ...] = (*SENSORS, "seq", "t")


def _log_process_entry() -> None:
    """``python -c`` entry of the log process: argv[1] is JSON {fd, path, kwargs}."""
    import sys
    from multiprocessing.connection import Connection

    from service.log.setup import inherit_logging

    inherit_logging()  # the parent's log format and level (the daemon's JSON lines, ...)
    a = json.loads(sys.argv[1])
    _log_process_main(Connection(a["fd"]), a["path"], a["kwargs"])


def _log_process_main(conn, path: str, kwargs: dict) -> None:
    """Child process of :class:`ProcessLogger`: write the forwarded blocks to the MCAP."""
    import signal as _signal

    from service.log import McapLogger

    # the parent decides when to stop (systemd and terminals signal the whole group): the
    # child ends on the parent's close or when the pipe closes because the parent died
    _signal.signal(_signal.SIGINT, _signal.SIG_IGN)
    _signal.signal(_signal.SIGTERM, _signal.SIG_IGN)
    try:
        lg = McapLogger(path, **kwargs)
    except Exception as e:
        conn.send(("error", f"{type(e).__name__}: {e}"))
        return
    conn.send(("paths", [str(p) for p in lg.paths]))
    n_paths = len(lg.paths)
    sent_failure = False
    try:
        while True:
            try:
                # wake now and then to report a failure of the background flush
                batch = conn.recv() if conn.poll(0.5) else ()
            except EOFError:  # the daemon died: finish the file with what we have
                break
            if batch is None:
                break
            try:
                _write_batch(lg, batch)
            except Exception:  # a write failure is kept in lg.failure (logged there)
                if lg.failure is None:
                    logging.getLogger("servowatch.log").exception("log process: bad batch")
            if lg.failure is not None and not sent_failure:
                conn.send(("failure", lg.failure))
                sent_failure = True
            if len(lg.paths) != n_paths:
                n_paths = len(lg.paths)
                conn.send(("paths", [str(p) for p in lg.paths]))
    finally:
        with contextlib.suppress(Exception):  # a failure is kept in lg.failure
            lg.close()
        with contextlib.suppress(OSError, ValueError):
            if lg.failure is not None and not sent_failure:
                conn.send(("failure", lg.failure))
            conn.send(("closed", [str(p) for p in lg.paths], lg.message_count))


def _write_batch(lg: Any, batch: Sequence[tuple]) -> None:
    """Write one batch of queued records (see :class:`ProcessLogger`)."""
    for rec in batch:
        if rec[0] == "b":  # (b, topic, t, names, values, int_fields)
            lg.log_block(rec[1], rec[2], rec[3], rec[4], int_fields=rec[5])
        elif rec[0] == "s":  # (s, topics, counts, t bytes, names, values bytes, int_fields)
            _, topics, counts, t, names, values, int_fields = rec
            t = np.frombuffer(t, np.float64)
            values = np.frombuffer(values, np.float64).reshape(len(t), len(names))
            lg.log_rows(topics, counts, t, names, values, int_fields=int_fields)
        elif rec[0] == "e":  # (e, topic, t, event)
            lg.log_event(rec[1], rec[2], rec[3])
        else:  # (l, topic, t, msg)
            lg.log(rec[1], rec[2], rec[3])


class ProcessLogger:
    """An ``McapLogger`` in a child process, fed through a pipe once per worker tick.

    Row encoding, compression and MCAP writing then run on another
    core instead of sharing the daemon's GIL with decoding and the monitors. Blocks go as
    the arrays they are (measurements too: the child decodes nothing). Same ``log``/``close``/``paths`` interface; ``commit``
    sends what was logged since the last call. If the daemon dies, the child sees the pipe
    close and finishes the file (a ``kill -9`` of both loses at most ``flush_s``).
    """

    def __init__(self, path: str | Path, **kwargs: Any) -> None:
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        # a plain child interpreter (not multiprocessing's spawn, which re-imports __main__)
        # talking over a socket pair; the child needs only service.log
        a, b = socket.socketpair()
        arg = json.dumps({"fd": b.fileno(), "path": str(path), "kwargs": kwargs})
        self._proc = subprocess.Popen(
            [sys.executable, "-c", "import service.log.proclog as p; p._log_process_entry()", arg],
            pass_fds=(b.fileno(),),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
        )
        b.close()
        self._conn = Connection(a.detach())
        self._buf: list[tuple] = []
        self._lock = threading.Lock()
        self._closed = False
        self.paths: list[Path] = []
        self.message_count = 0
        self.failure: str | None = None  # the log process's first write/flush failure
        kind, *rest = self._conn.recv()
        if kind == "error":
            self._proc.wait(5)
            raise OSError(f"{path}: cannot open the MCAP log: {rest[0]}")
        self.paths = [Path(p) for p in rest[0]]

    def log(self, topic: str, t: float, msg: Any) -> None:
        """Queue one message (sent at the next ``commit``)."""
        self._buf.append(("l", topic, t, msg))

    def log_event(self, topic: str, t: float, event: Any) -> None:
        """Queue one event (``McapLogger.log_event``: a ``servowatch.Event`` row)."""
        self._buf.append(("e", topic, t, dict(event)))

    def log_block(
        self, topic: str, t: Any, names: Sequence[str], values: Any, *, int_fields=()
    ) -> None:
        """Queue N messages of one topic as arrays (``McapLogger.log_block``)."""
        self._buf.append(("b", topic, t, tuple(names), values, tuple(int_fields)))

    def log_blocks(
        self,
        topics: Sequence[str],
        counts: Sequence[int],
        t: Any,
        names: Sequence[str],
        values: Any,
        *,
        int_fields=(),
    ) -> None:
        """Queue consecutive blocks of several topics with the same fields as one record:
        rows ``sum(counts[:i]) :`` + ``counts[i]`` of ``t`` and ``values`` on ``topics[i]``
        (sent as float64 bytes: a pickled numpy array costs tens of microseconds)."""
        t = np.ascontiguousarray(t, np.float64).tobytes()
        values = np.ascontiguousarray(values, np.float64).tobytes()
        self._buf.append(("s", list(topics), list(counts), t, tuple(names), values,
                          tuple(int_fields)))  # fmt: skip

    def _handle(self, kind: str, rest: list) -> None:
        if kind in ("paths", "closed"):
            self.paths = [Path(p) for p in rest[0]]
        if kind == "closed":
            self.message_count = rest[1]
        if kind == "failure" and self.failure is None:
            self.failure = str(rest[0])

    def _lost(self, why: str) -> None:
        if self.failure is None:
            self.failure = why
            logging.getLogger("servowatch.log").error("log process: %s", why)

    def _poll(self) -> None:
        while self._conn.poll():
            self._handle(*self._recv())
        code = self._proc.poll()
        if code is not None and not self._closed:
            self._lost(f"the log process exited with code {code}")

    def _recv(self) -> tuple[str, list]:
        kind, *rest = self._conn.recv()
        return kind, rest

    def commit(self) -> None:
        """Send the queued messages to the log process."""
        with self._lock:
            if self._closed:
                return
            buf, self._buf = self._buf, []
            try:
                if buf and self.failure is None:
                    self._conn.send(buf)
                self._poll()
            except (OSError, EOFError) as e:  # the log process is gone
                self._lost(f"the log process is gone: {type(e).__name__}: {e}")

    def close(self, timeout: float = 60.0) -> None:
        """Send the rest, finish the file, wait for the log process. Idempotent."""
        self.commit()
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._conn.send(None)
                deadline = time.monotonic() + timeout
                while time.monotonic() < deadline and self._proc.poll() is None:
                    if self._conn.poll(0.1):
                        kind, rest = self._recv()
                        self._handle(kind, rest)
                        if kind == "closed":
                            break
                while self._conn.poll():  # what came before the process ended
                    self._handle(*self._recv())
            except (EOFError, OSError):
                pass
            try:
                self._proc.wait(timeout)
            except Exception:
                self._proc.kill()
            self._conn.close()
