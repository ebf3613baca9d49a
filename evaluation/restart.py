"""A router restart mid-stream, every piece in its own process on loopback: measures how
soon the stream resumes and which samples are lost (tests/test_resilience_e2e.py and
bench/restart.py).

Topology: router R1 on port P1; the virtual actuator connects to R1. With ``link="daemon"``
a second router R2 (port P2) connects to R1 and the daemon connects to R2, and R2 is the one
killed; with ``link="actuator"`` the daemon connects to R1 too and R1 is killed. The killed
router gets ``kill -9`` and is started again on the same port ``down_s`` later.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Literal

from service.zenoh_util import free_port, loopback, make_config

__all__ = ["run_restart"]

KEY = "fleet/AC001/elevator_L/meas"


def _cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "service.cli", *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ),
    )  # fmt: skip


def servowatch_exe() -> list[str]:
    """The ``servowatch`` console script next to this interpreter (the command a user types),
    else ``python -m service.cli`` (the same code)."""
    exe = Path(sys.executable).with_name("servowatch")
    return [str(exe)] if exe.is_file() else [sys.executable, "-m", "service.cli"]


def _router(listen: str, *connect: str) -> subprocess.Popen:
    """``servowatch router`` in its own process, listening on ``listen``."""
    args = ["router", "--listen", listen]
    for c in connect:
        args += ["--connect", c]
    return subprocess.Popen(
        [*servowatch_exe(), *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ),
    )  # fmt: skip


def _listening(port: int, timeout: float = 60.0) -> float:
    """Wait until 127.0.0.1:port accepts a connection; time.time() then."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), 0.1).close()
            return time.time()
        except OSError:
            time.sleep(0.01)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout} s")


def run_restart(
    tmp: Path,
    *,
    link: Literal["actuator", "daemon"] = "actuator",
    rate_hz: float = 250.0,
    down_s: float = 1.0,
    before_s: float = 3.0,
    after_s: float = 3.0,
    cache_s: float = 10.0,
) -> dict[str, Any]:
    """Run the restart once (the routers are ``servowatch router``); returns the figures
    (``listen_s``: from the restarted router's spawn to its port accepting; ``resume_s``: from
    it listening to the daemon holding a sample published after that; ``flowing_s``: from its
    spawn to that sample, the chain flowing again; ``lost``: seq numbers the
    daemon never accepted; the daemon's final ``gaps``, ``missed``, ``samples``)."""
    import zenoh

    p1, p2 = free_port(), free_port()
    procs: list[subprocess.Popen] = []
    r1 = _router(loopback(p1))
    procs.append(r1)
    _listening(p1)
    r2 = None
    dport = p1
    if link == "daemon":
        r2 = _router(loopback(p2), loopback(p1))
        procs.append(r2)
        _listening(p2)
        dport = p2
    log = tmp / "restart.mcap"
    common = ("--mode", "client")
    daemon = _cli("run", "--log", str(log), "--no-rotate", "--connect", loopback(dport), *common)
    procs.append(daemon)
    q = zenoh.open(make_config("client", connect=[loopback(dport)]))

    def status() -> dict | None:
        for reply in q.get("monitor/*/*/status", timeout=0.3):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def act() -> dict:
        st = status()
        return {} if st is None else st["actuators"].get(KEY, {})

    try:
        deadline = time.monotonic() + 120
        while status() is None:
            if time.monotonic() > deadline:
                raise TimeoutError("the daemon's status never answered")
            time.sleep(0.2)
        actuator = _cli(
            "actuator", "--rate", str(rate_hz), "--cache-s", str(cache_s),
            "--connect", loopback(p1), *common,
        )  # fmt: skip
        procs.append(actuator)
        while act().get("samples", 0) < rate_hz * before_s:
            if time.monotonic() > deadline:
                raise TimeoutError(f"no stream reached the daemon: {status()}")
            time.sleep(0.1)
        victim, vport = (r2, p2) if link == "daemon" else (r1, p1)
        assert victim is not None
        victim.send_signal(signal.SIGKILL)
        victim.wait(10)
        t_kill = time.time()
        time.sleep(down_s)
        t_spawn = time.time()
        procs.append(_router(loopback(vport), *([loopback(p1)] if link == "daemon" else [])))
        t_back = _listening(vport)
        resume = flowing = None
        while time.time() - t_back < 30:
            a = act()
            if a.get("last_t") is not None and a["last_t"] >= t_back:
                now = time.time()
                resume, flowing = now - t_back, now - t_spawn
                break
            time.sleep(0.02)
        time.sleep(after_s)
        final = act()
        actuator.send_signal(signal.SIGTERM)
        actuator.wait(30)
        time.sleep(1.0)
        final = act()
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(60)
    finally:
        q.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(10)
    from service.log import read_log

    seqs = sorted(int(r[2]["seq"]) for r in read_log(log, [f"/{KEY}"]))
    lost = sorted(set(range(seqs[0], seqs[-1] + 1)) - set(seqs)) if seqs else []
    return {
        "link": link,
        "rate_hz": rate_hz,
        "down_s": down_s,
        "outage_s": t_back - t_kill,
        "listen_s": t_back - t_spawn,
        "resume_s": resume,
        "flowing_s": flowing,
        "logged": len(seqs),
        "first_seq": seqs[0] if seqs else None,
        "last_seq": seqs[-1] if seqs else None,
        "lost": len(lost),
        "lost_seq": lost[:20],
        "gaps": final.get("gaps"),
        "missed": final.get("missed"),
        "bad": final.get("bad"),
    }
