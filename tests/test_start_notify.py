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
