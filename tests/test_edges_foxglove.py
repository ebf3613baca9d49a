"""The live feed's guard, round three (issue 50): viewers cannot be locked out (idle upgraded
connections are cut, connections in the handshake have a short deadline and do not count
against viewers, one address cannot hold every slot), and no local process reaches the SDK's
private port but the guard. Raw sockets on loopback, against a real ``FoxgloveFeed``."""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import socket
import subprocess
import sys
import time

from _foxglove_ws import FoxgloveClient
from test_foxglove_guard import _handshake

from service.edge.foxglove_feed import FoxgloveFeed
from service.edge.foxglove_guard import GuardLimits


def _feed(**limits) -> FoxgloveFeed:
    return FoxgloveFeed("127.0.0.1", 0, limits=GuardLimits(**limits))


def _viewer_in(port: int, timeout: float) -> tuple[float, FoxgloveClient]:
    """Seconds until a viewer's handshake succeeds (retrying), and the viewer."""
    t0 = time.monotonic()
    while True:
        try:
            return time.monotonic() - t0, FoxgloveClient("127.0.0.1", port).connect(timeout=2)
        except (OSError, AssertionError, RuntimeError, ValueError):
            if time.monotonic() - t0 > timeout:
                raise
            time.sleep(0.2)


def _bound(addr: str, port: int) -> socket.socket:
    s = socket.socket()
    s.bind((addr, 0))
    s.settimeout(10)
    s.connect(("127.0.0.1", port))
    return s


def test_idle_connections_cannot_lock_a_viewer_out():
    """The probe's pattern: 16 upgraded connections that never send nor read, then a viewer
    that must get in within a few seconds and then stays (it answers the guard's pings)."""
    f = _feed(max_connections=16, idle_s=2.0, max_per_address=16)
    idle = []
    try:
        p = f.port
        for k in range(16):  # one user may hold every slot here: only idle_s frees them
            s = _bound(f"127.0.0.{k + 2}", p)
            line, s = _handshake_on(s, p)
            assert " 101 " in line, line
            idle.append(s)
        assert f.status()["guard"]["connections"] == 16
        took, viewer = _viewer_in(p, timeout=10.0)
        assert took < 4.0, took
        # the viewer stays connected well past idle_s: it answers the pings
        _answer_pings(viewer, 6.0)
        st = f.status()["guard"]
        assert st["connections"] == 1, st
        assert st["cut"].get("idle") == 16, st
        assert st["idle_s"] == 2.0
        viewer.close()
    finally:
        for s in idle:
            s.close()
        f.close()


def _answer_pings(c: FoxgloveClient, seconds: float) -> None:
    """Read ``c``'s frames for ``seconds``, answering pings as a browser does (a cut raises
    ConnectionError)."""
    c.sock.settimeout(0.3)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with contextlib.suppress(TimeoutError):
            c._frame()


def _handshake_on(s: socket.socket, port: int) -> tuple[str, socket.socket]:
    return _handshake(port, {"Host": f"127.0.0.1:{port}"}, s)


def test_connections_in_the_handshake_do_not_count_against_viewers():
    """The probe's slowloris: silent TCP connections renewed every 4 s gave every viewer 503
    (0 of 39 handshakes); now they have a short deadline and a cap of their own."""
    f = _feed(max_connections=16, head_s=1.0)
    silent = []
    try:
        ok = 0
        t_end = time.monotonic() + 5.0
        while time.monotonic() < t_end:  # renew 40 silent connections every 0.8 s
            for s in silent:
                s.close()
            silent = [socket.create_connection(("127.0.0.1", f.port), timeout=5)
                      for _ in range(40)]  # fmt: skip
            for _ in range(3):
                line, s = _handshake(f.port, {"Host": f"127.0.0.1:{f.port}"})
                s.close()
                ok += " 101 " in line
            time.sleep(0.8)
        assert ok >= 15, ok
        st = f.status()["guard"]
        assert st["max_pending"] >= 40 or st["refused"].get("pending_full", 0) > 0, st
    finally:
        for s in silent:
            s.close()
        f.close()


_HOLD = (
    "import base64, os, socket, sys, time\n"
    "p = int(sys.argv[1]); s = socket.create_connection(('127.0.0.1', p), timeout=10)\n"
    "k = base64.b64encode(os.urandom(16)).decode()\n"
    "s.sendall((f'GET / HTTP/1.1\\r\\nHost: 127.0.0.1:{p}\\r\\nUpgrade: websocket\\r\\n'\n"
    "  f'Connection: Upgrade\\r\\nSec-WebSocket-Key: {k}\\r\\nSec-WebSocket-Version: 13\\r\\n'\n"
    "  'Sec-WebSocket-Protocol: foxglove.sdk.v1\\r\\n\\r\\n').encode())\n"
    "print(s.recv(4096).split(b'\\r\\n')[0].decode(), flush=True); time.sleep(5)\n"
)


def test_one_address_or_local_user_cannot_hold_every_slot():
    """Every local process connects from 127.0.0.1, so a local client's slots are counted by
    its user (the uid owning the peer socket): this user's third connection is refused from
    any loopback address, another user's is let in."""
    f = _feed(max_connections=4, max_per_address=2)
    held = []
    try:
        for _ in range(2):
            line, s = _handshake_on(_bound("127.0.0.1", f.port), f.port)
            assert " 101 " in line, line
            held.append(s)
        for addr in ("127.0.0.1", "127.0.0.3"):
            line, s = _handshake_on(_bound(addr, f.port), f.port)
            s.close()
            assert " 503 " in line, (addr, line)
        st = f.status()["guard"]
        assert st["refused"] == {"per_address": 2} and st["max_per_address"] == 2, st
        if os.geteuid() == 0 and shutil.which("setpriv"):
            nobody = pwd.getpwnam("nobody")
            r = subprocess.run(
                ["setpriv", f"--reuid={nobody.pw_uid}", f"--regid={nobody.pw_gid}",
                 "--clear-groups", sys.executable, "-I", "-c", _HOLD, str(f.port)],
                capture_output=True, text=True, timeout=30,
            )  # fmt: skip
            assert " 101 " in r.stdout, r.stdout + r.stderr
    finally:
        for s in held:
            s.close()
        f.close()


_CONNECT = (
    "import socket, sys\n"
    "s = socket.socket(); s.settimeout(3); s.bind((sys.argv[2], 0))\n"
    "try:\n"
    "    s.connect(('127.0.0.1', int(sys.argv[1]))); print('connected')\n"
    "except OSError as e:\n"
    "    print('refused', type(e).__name__)\n"
)


def test_only_the_guard_reaches_the_sdks_private_port():
    """The probe found the SDK's port in /proc/net/tcp and connected to it, as ``nobody``,
    with any Origin. Now the kernel drops every connection to it that does not carry the
    guard's TCP-MD5 key (RFC 2385), whatever its user (this process's, and ``nobody``) and
    its source address (an exact key for 127.0.0.1 would let 127.0.0.2 in)."""
    f = _feed()
    try:
        sdk = int(f.server.port)
        st = f.status()["guard"]
        assert st["upstream_private"] is True, st
        for src in ("127.0.0.1", "127.0.0.2"):  # from any source address
            r = subprocess.run([sys.executable, "-c", _CONNECT, str(sdk), src],
                               capture_output=True, text=True, timeout=30)  # fmt: skip
            assert r.stdout.startswith("refused"), (src, r.stdout + r.stderr)
        if os.geteuid() == 0 and shutil.which("setpriv"):
            nobody = pwd.getpwnam("nobody")
            r = subprocess.run(
                ["setpriv", f"--reuid={nobody.pw_uid}", f"--regid={nobody.pw_gid}",
                 "--clear-groups", sys.executable, "-I", "-c", _CONNECT, str(sdk), "127.0.0.1"],
                capture_output=True, text=True, timeout=30,
            )  # fmt: skip
            assert r.stdout.startswith("refused"), r.stdout + r.stderr
        # the guard still reaches it
        c = FoxgloveClient("127.0.0.1", f.port).connect()
        c.close()
        assert f.status()["guard"]["listener"] == "ok"
    finally:
        f.close()
