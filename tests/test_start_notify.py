"""A cold start systemd survives (issue 54): while it compiles and loads, the daemon tells
systemd to extend its start timeout (sd_notify ``EXTEND_TIMEOUT_USEC``) and reports READY
only once started. The notify protocol on a real AF_UNIX datagram socket, as systemd reads
it."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from service.daemon.systemd import extending_start, notify_ready


class Notes:
    """A bound notify socket read continuously, as systemd does: (monotonic time, text)."""

    def __init__(self, path):
        self.path = str(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.settimeout(0.05)
        self.got: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._read, daemon=True)
        self._th.start()

    def _read(self):
        while not self._stop.is_set():
            try:
                self.got.append((time.monotonic(), self.sock.recv(4096).decode()))
            except TimeoutError:
                continue

    def close(self):
        time.sleep(0.1)
        self._stop.set()
        self._th.join(2)
        self.sock.close()

    @property
    def texts(self) -> list[str]:
        return [t for _, t in self.got]


@pytest.fixture
def notes(tmp_path):
    n = Notes(tmp_path / "notify")
    yield n
    n.close()


def test_a_long_start_extends_the_timeout_until_ready(notes):
    env = {"NOTIFY_SOCKET": notes.path}
    with extending_start("compiling", every_s=0.05, env=env) as ext:
        time.sleep(0.5)  # a compile that outlasts many extension periods
        notify_ready(env)
        time.sleep(0.2)  # nothing more after READY
    notes.close()
    texts = notes.texts
    assert texts[-1] == "READY=1"
    ext_notes = texts[:-1]
    assert len(ext_notes) >= 6 and ext.sent == len(ext_notes)
    # each extends by 3 periods (150 ms) and says why; one comes every 50 ms
    assert set(ext_notes) == {"EXTEND_TIMEOUT_USEC=150000\nSTATUS=compiling"}
    times = [t for t, _ in notes.got[:-1]]
    assert max(b - a for a, b in zip(times, times[1:], strict=False)) < 0.15


def test_the_extensions_stop_after_max_s(notes):
    env = {"NOTIFY_SOCKET": notes.path}
    with extending_start("stuck", every_s=0.02, max_s=0.1, env=env):
        time.sleep(0.4)  # a start stuck past max_s is left to systemd's timeout
    notes.close()
    assert 3 <= len(notes.texts) <= 7


def test_no_notify_socket_no_thread():
    with extending_start("x", env={}) as ext:
        assert ext is None
    assert not notify_ready({})


@pytest.mark.slow
def test_servowatch_run_extends_its_start_then_is_ready_once_it_answers(net, tmp_path):
    """``servowatch run`` under the notify protocol (as systemd starts it): the first
    datagrams extend the start timeout, READY=1 comes after them, once the daemon answers its
    status queryable, and no extension follows READY."""
    notes = Notes(tmp_path / "notify")
    try:
        d = net.start("run", "--log", str(tmp_path / "r.mcap"), "--no-rotate",
                      env={"NOTIFY_SOCKET": notes.path})  # fmt: skip
        deadline = time.monotonic() + 120
        while "READY=1" not in notes.texts and time.monotonic() < deadline:
            time.sleep(0.05)
        t_ready = next(t for t, x in notes.got if x == "READY=1")
        assert net.status(timeout=2.0) is not None  # it answers once READY
        time.sleep(0.5)
        d.terminate()
        d.communicate(timeout=30)
    finally:
        notes.close()
    texts = notes.texts
    k = texts.index("READY=1")
    assert k >= 1 and all(
        x.startswith("EXTEND_TIMEOUT_USEC=30000000\nSTATUS=starting") for x in texts[:k]
    )
    assert not any(x.startswith("EXTEND") for x in texts[k + 1 :])
    assert texts[-1] == "STOPPING=1" and t_ready > notes.got[0][0]


def test_the_compile_estimate_says_what_it_assumes():
    from service.cli.warmup import ESTIMATE_S, estimate_text

    idle = estimate_text(["monitor", "log"], jobs=2, load=0.0)
    cpu = ESTIMATE_S["monitor"] + ESTIMATE_S["log"]
    assert idle.startswith(f"first run, about {cpu / 2:.0f} s if 2 cores are idle: {cpu:.0f} s "
                           "of CPU measured on a 2-core VM")  # fmt: skip
    assert "load average" not in idle
    busy = estimate_text(["monitor", "log"], jobs=2, load=13.0)
    assert "more now: load average 13.0" in busy
    assert "if 1 core is idle" in estimate_text(["log"], jobs=1, load=0.0)


def test_a_kernel_is_announced_once_across_the_parts(tmp_path):
    """Two parts (processes) that compile the same kernel, or one kernel compiled for two
    signatures, print its line once (issue 54: one kernel's line printed twice)."""
    from service.cli.warmup import _SeenKernels

    a, b = _SeenKernels(str(tmp_path)), _SeenKernels(str(tmp_path))
    assert a.first("service.monitor.kernels.bank_step")
    assert not a.first("service.monitor.kernels.bank_step")  # a second signature
    assert not b.first("service.monitor.kernels.bank_step")  # another part's process
    assert b.first("service.log.codec_read._scan")


def test_the_unit_and_the_image_warm_up_before_the_start():
    """deploy/servowatch.service compiles in ExecStartPre, lets it extend the start
    (NotifyAccess=exec), keeps the kernels in a cache it may write under ProtectSystem=strict;
    the Containerfile compiles at build, as the run user, into the cache the image uses."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    unit = (root / "deploy" / "servowatch.service").read_text()
    kv = dict(re.findall(r"^(\w+)=(.*)$", unit, re.M))
    assert kv["ExecStartPre"].endswith("servowatch warmup")
    assert kv["NotifyAccess"] == "exec" and kv["Type"] == "notify"
    cache = re.search(r"^Environment=NUMBA_CACHE_DIR=(\S+)$", unit, re.M).group(1)
    assert cache.startswith(f"/var/cache/{kv['CacheDirectory']}/")
    assert f"/var/cache/{kv['CacheDirectory']}" in kv["ReadWritePaths"].split()
    assert "LogsDirectory" not in kv  # nothing wrote there
    image = (root / "deploy" / "Containerfile").read_text()
    env = re.search(r"^ENV NUMBA_CACHE_DIR=(\S+)$", image, re.M)
    warm = image.index("servowatch warmup")
    assert env and image.index(env.group(0)) < warm
    assert image.rindex("USER servowatch", 0, warm) > image.rfind("USER root", 0, warm)
