"""systemd's notify protocol (sd_notify(3)) and watchdog period, without libsystemd.

``sd_notify`` is a datagram on the AF_UNIX socket named by ``NOTIFY_SOCKET``; about twenty
lines, tested against a real socket (``tests/test_daemon.py``), so no package is needed.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

from service.daemon.ratelimit import RateLimitedLog

__all__ = ["sd_notify", "watchdog_interval"]

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
