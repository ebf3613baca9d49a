"""systemd's notify protocol (sd_notify(3)) and watchdog period, without libsystemd.

``sd_notify`` is a datagram on the AF_UNIX socket named by ``NOTIFY_SOCKET``; about twenty
lines, tested against a real socket (``tests/test_daemon.py``), so no package is needed.

A start that takes long (the first run compiles the kernels: a minute, several under load)
runs inside :func:`extending_start`: a thread sends ``EXTEND_TIMEOUT_USEC`` every
``EXTEND_EVERY_S`` so systemd's ``TimeoutStartSec`` does not kill it, up to ``MAX_START_S`` in
all (a start stuck longer is then killed as it should be); :func:`notify_ready` ends it and
sends ``READY=1``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
from collections.abc import Iterator, Mapping

from service.daemon.ratelimit import RateLimitedLog

__all__ = [
    "EXTEND_EVERY_S",
    "MAX_START_S",
    "extending_start",
    "notify_ready",
    "sd_notify",
    "watchdog_interval",
]

#: how often a long start tells systemd it is alive [s]; each message extends by 3 times that
EXTEND_EVERY_S = 10.0
#: a start (compile included) that takes longer is left to systemd's timeout [s]
MAX_START_S = 900.0

log = logging.getLogger("servowatch.daemon")
_FULL_LOG = RateLimitedLog(log, 30.0)


def sd_notify(state: str, env: Mapping[str, str] | None = None) -> bool:
    """Send ``state`` (``READY=1``, ``WATCHDOG=1``, ...) to systemd's ``NOTIFY_SOCKET``.

    A datagram on the unix socket named by the variable (``@`` = abstract namespace), as
    sd_notify(3) does. Returns False (and does nothing) when the variable is unset.
    """
    addr = (env if env is not None else os.environ).get("NOTIFY_SOCKET")
    if not addr:
        return False
    if addr.startswith("@"):
        addr = "\0" + addr[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
            s.setblocking(False)  # a full receiver queue must never stall the worker
            s.sendto(state.encode(), addr)
        return True
    except BlockingIOError:
        _FULL_LOG.warning("notify", "sd_notify(%s): the notify socket is full; dropped", state)
        return False
    except OSError as e:
        log.warning("sd_notify(%s) failed: %s", state, e)
        return False


def watchdog_interval(env: Mapping[str, str] | None = None) -> float | None:
    """Half of systemd's ``WATCHDOG_USEC`` in seconds (how often to ping), or None."""
    env = env if env is not None else os.environ
    usec = env.get("WATCHDOG_USEC")
    pid = env.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        return max(0.05, int(usec) / 2e6)
    except ValueError:
        return None


class _Extender:
    """The thread of :func:`extending_start`."""

    def __init__(self, status: str, every_s: float, max_s: float, env: Mapping[str, str] | None):
        self.status, self.every_s, self.max_s, self.env = status, every_s, max_s, env
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sd-extend", daemon=True)

    def _run(self) -> None:
        t0 = time.monotonic()
        usec = int(3 * self.every_s * 1e6)
        while time.monotonic() - t0 < self.max_s:
            if sd_notify(f"EXTEND_TIMEOUT_USEC={usec}\nSTATUS={self.status}", self.env):
                self.sent += 1
            if self._stop.wait(self.every_s):
                return

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(5)


_current: list[_Extender] = []
_current_lock = threading.Lock()


@contextlib.contextmanager
def extending_start(
    status: str,
    *,
    every_s: float = EXTEND_EVERY_S,
    max_s: float = MAX_START_S,
    env: Mapping[str, str] | None = None,
) -> Iterator[_Extender | None]:
    """While the block runs (and until :func:`notify_ready`, whichever comes first), tell
    systemd every ``every_s`` that the start goes on: ``EXTEND_TIMEOUT_USEC`` (3 x
    ``every_s``) and ``STATUS=<status>``, for ``max_s`` at most. Nothing without
    ``NOTIFY_SOCKET`` (yields None)."""
    if not (env if env is not None else os.environ).get("NOTIFY_SOCKET"):
        yield None
        return
    ext = _Extender(status, every_s, max_s, env)
    with _current_lock:
        _current.append(ext)
    ext._thread.start()
    try:
        yield ext
    finally:
        ext.stop()
        with _current_lock:
            if ext in _current:
                _current.remove(ext)


def notify_ready(env: Mapping[str, str] | None = None) -> bool:
    """End every :func:`extending_start` still running, then send ``READY=1``."""
    with _current_lock:
        exts = list(_current)
    for ext in exts:
        ext.stop()
    return sd_notify("READY=1", env)
