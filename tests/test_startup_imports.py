"""The light commands start without the heavy machinery (issue 34): ``servowatch --help``,
``router``, ``status`` and ``inject`` import neither numba, scipy, matplotlib nor the monitor
(its bank, kernels, UKF and the compiled models), each checked on ``sys.modules`` of a real
run in its own process. Start-up times: bench/startup.py."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service.zenoh_util import free_port, loopback

PROBE = Path(__file__).with_name("_modules_probe.py")
HEAVY = (
    "numba",
    "scipy",
    "matplotlib",
    "filterpy",
    "service.monitor.bank",
    "service.monitor.kernels",
    "service.monitor.fleet",
    "service.monitor.ukf",
    "models.compiled",
    "models.eha_reduced",
    "models.eha_reduced_wh",
)


def _heavy(stderr: str) -> list[str]:
    line = next(x for x in stderr.splitlines() if x.startswith("MODULES "))
    mods = json.loads(line[len("MODULES ") :])
    return sorted(m for m in mods if any(m == h or m.startswith(h + ".") for h in HEAVY))


def _probe(*args: str, ok: tuple[int, ...]) -> list[str]:
    r = subprocess.run(
        [sys.executable, str(PROBE), *args], capture_output=True, text=True, timeout=120
    )
    assert r.returncode in ok, r.stderr[-2000:]
    return _heavy(r.stderr)


def _start_router(port: int) -> subprocess.Popen:
    p = subprocess.Popen(
        [sys.executable, str(PROBE), "router", "--listen", loopback(port)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 60
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), 0.1).close()
            return p
        except OSError:
            if p.poll() is not None or time.monotonic() > deadline:
                p.kill()
                raise AssertionError(f"no router: {p.communicate()[1]}") from None
            time.sleep(0.02)


@pytest.fixture(scope="module")
def router():
    port = free_port()
    p = _start_router(port)
    yield loopback(port), p
    if p.poll() is None:
        p.kill()
        p.wait(10)


def test_help_imports_nothing_heavy():
    assert _probe("--help", ok=(0,)) == []


@pytest.mark.parametrize("cmd", ["router", "status", "inject", "run", "replay", "rul"])
def test_command_help_imports_nothing_heavy(cmd):
    assert _probe(cmd, "--help", ok=(0,)) == []


def test_status_imports_nothing_heavy(router):
    ep, _ = router
    # no daemon on this router: exit 3, after a real session and query
    assert _probe("status", "--timeout", "0.2", "--connect", ep, ok=(3,)) == []


def test_inject_imports_nothing_heavy(router):
    ep, _ = router
    # no virtual actuator: refused after a liveliness query (exit 1)
    args = ("inject", "--fault", "leak", "--value", "1e-12", "--timeout", "0.3", "--connect", ep)
    assert _probe(*args, ok=(1,)) == []


def test_router_imports_nothing_heavy(router):
    _, p = router
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 0, err[-2000:]
    assert _heavy(err) == []
