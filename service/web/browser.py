"""Headless Chromium for the fleet page: its DOM after the page's scripts ran, and a PNG of
it. Used by ``servowatch web --snapshot`` and by the page's browser tests.

Chromium runs with a fresh profile and without its background networking (no update, sync
or component fetches: this project talks to loopback only), ``--no-sandbox`` so it runs as
root in a container, and a virtual-time budget that lets the page's fetches finish before the
DOM is read or the picture taken.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

__all__ = ["BrowserError", "find_chromium", "dump_dom", "screenshot"]

_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserError(RuntimeError):
    """No Chromium, or Chromium failed."""


def find_chromium() -> str | None:
    """``$SERVOWATCH_CHROMIUM``, else the first of chromium, chromium-browser, google-chrome
    on PATH; None when there is none."""
    env = os.environ.get("SERVOWATCH_CHROMIUM")
    if env:
        return env if Path(env).exists() or shutil.which(env) else None
    for n in _NAMES:
        found = shutil.which(n)
        if found:
            return found
    return None


def _run(args: list[str], timeout_s: float) -> subprocess.CompletedProcess[bytes]:
    exe = find_chromium()
    if exe is None:
        raise BrowserError(
            "no Chromium found (install Debian's chromium, or set SERVOWATCH_CHROMIUM)"
        )
    with tempfile.TemporaryDirectory(
        prefix="servowatch-chromium-", ignore_cleanup_errors=True
    ) as profile:
        cmd = [
            exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
            "--no-first-run", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--disable-extensions", "--disable-dev-shm-usage",
            f"--user-data-dir={profile}", *args,
        ]  # fmt: skip
        # its own process group, so a timeout ends Chromium's helper processes too
        proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True
        )
        try:
            out, err = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired as e:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise BrowserError(f"chromium took more than {timeout_s:g} s") from e
        res = subprocess.CompletedProcess(cmd, proc.returncode, out, err)
    if res.returncode != 0:
        tail = res.stderr.decode(errors="replace").strip().splitlines()[-3:]
        raise BrowserError(f"chromium exited {res.returncode}: {' | '.join(tail)}")
    return res


def dump_dom(url: str, *, budget_ms: int = 5000, timeout_s: float = 60.0) -> str:
    """The serialized DOM of ``url`` once its scripts ran (``--dump-dom``)."""
    res = _run([f"--virtual-time-budget={budget_ms}", "--dump-dom", url], timeout_s)
    return res.stdout.decode("utf-8", errors="replace")


def screenshot(
    url: str,
    out: str | os.PathLike[str],
    *,
    size: tuple[int, int] = (1500, 1100),
    budget_ms: int = 5000,
    timeout_s: float = 60.0,
) -> Path:
    """A PNG of ``url`` at ``size`` pixels (width, height), written to ``out``."""
    path = Path(out).resolve()
    path.parent.mkdir(parents=True, exist_ok=True)
    _run(
        [f"--virtual-time-budget={budget_ms}", f"--window-size={size[0]},{size[1]}",
         f"--screenshot={path}", "--hide-scrollbars", url],
        timeout_s,
    )  # fmt: skip
    if not path.exists() or path.stat().st_size == 0:
        raise BrowserError(f"chromium wrote no picture to {path}")
    return path
