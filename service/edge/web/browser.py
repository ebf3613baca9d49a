"""Headless Chromium for the fleet page: its DOM after the page's scripts ran, and a PNG of
it. Used by ``servowatch web --snapshot`` and by the page's browser tests.

Chromium runs with a fresh profile and without its background networking (no update, sync
or component fetches: this project talks to loopback only), ``--no-sandbox`` so it runs as
root in a container, and a virtual-time budget that lets the page's fetches finish before the
DOM is read or the picture taken.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ["BrowserError", "find_chromium", "dump_dom", "evaluate", "screenshot"]

_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserError(RuntimeError):
    """No Chromium, or Chromium failed."""


# headless, and none of Chromium's own network traffic (a closed network refuses it)
_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-extensions", "--disable-dev-shm-usage",
)  # fmt: skip


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
            exe, *_FLAGS,
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


class _Pipe:
    """The DevTools protocol over ``--remote-debugging-pipe``: JSON messages ended by NUL,
    written to Chromium's fd 3, read from its fd 4."""

    def __init__(self, w: int, r: int) -> None:
        self.w, self.r, self.buf, self.n = w, r, b"", 0

    def call(self, method: str, deadline: float, session: str | None = None, **params) -> dict:
        self.n += 1
        msg: dict[str, Any] = {"id": self.n, "method": method, "params": params}
        if session is not None:
            msg["sessionId"] = session
        os.write(self.w, json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" not in self.buf:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self.r], [], [], left)[0]:
                    raise BrowserError(f"chromium did not answer {method} in time")
                chunk = os.read(self.r, 1 << 16)
                if not chunk:
                    raise BrowserError("chromium closed its DevTools pipe")
                self.buf += chunk
            raw, self.buf = self.buf.split(b"\0", 1)
            ans = json.loads(raw)
            if ans.get("id") == self.n:
                if "error" in ans:
                    raise BrowserError(f"{method}: {ans['error'].get('message')}")
                return ans.get("result", {})


def evaluate(
    url: str,
    expression: str,
    *,
    size: tuple[int, int] = (1280, 900),
    ready: str = "true",
    timeout_s: float = 60.0,
) -> Any:
    """The value of the JavaScript ``expression`` on ``url`` in a viewport of ``size`` CSS
    pixels (width, height), once the expression ``ready`` is true (polled every 0.1 s), over
    the DevTools protocol on a pipe (no port opened). For a page's layout: widths, overflow."""
    exe = find_chromium()
    if exe is None:
        raise BrowserError(
            "no Chromium found (install Debian's chromium, or set SERVOWATCH_CHROMIUM)"
        )
    to_chrome_r, to_chrome_w = os.pipe()
    from_chrome_r, from_chrome_w = os.pipe()
    import fcntl

    # out of the way of 3 and 4 first, so the dup2 below never overwrites the other pipe;
    # close-on-exec, as every other descriptor of this process: only 3 and 4 are inherited
    hi_r = fcntl.fcntl(to_chrome_r, fcntl.F_DUPFD_CLOEXEC, 10)
    hi_w = fcntl.fcntl(from_chrome_w, fcntl.F_DUPFD_CLOEXEC, 10)

    def child_fds() -> None:
        os.dup2(hi_r, 3)
        os.dup2(hi_w, 4)

    deadline = time.monotonic() + timeout_s
    with tempfile.TemporaryDirectory(
        prefix="servowatch-chromium-", ignore_cleanup_errors=True
    ) as profile:
        cmd = [
            exe, *_FLAGS,
            "--hide-scrollbars", f"--window-size={size[0]},{size[1]}",
            "--remote-debugging-pipe", f"--user-data-dir={profile}", "about:blank",
        ]  # fmt: skip
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
            close_fds=False, preexec_fn=child_fds,  # noqa: PLW1509 (two dup2 only)
        )  # fmt: skip
        for fd in (to_chrome_r, from_chrome_w, hi_r, hi_w):
            os.close(fd)
        pipe = _Pipe(to_chrome_w, from_chrome_r)
        try:
            tid = pipe.call("Target.createTarget", deadline, url="about:blank")["targetId"]
            sid = pipe.call("Target.attachToTarget", deadline, targetId=tid, flatten=True)[
                "sessionId"
            ]
            pipe.call(
                "Emulation.setDeviceMetricsOverride", deadline, sid,
                width=size[0], height=size[1], deviceScaleFactor=1, mobile=False,
            )  # fmt: skip
            pipe.call("Page.navigate", deadline, sid, url=url)

            def value(expr: str) -> Any:
                r = pipe.call("Runtime.evaluate", deadline, sid, expression=expr,
                              returnByValue=True)  # fmt: skip
                if "exceptionDetails" in r:
                    raise BrowserError(f"{expr}: {r['exceptionDetails'].get('text')}")
                return r["result"].get("value")

            # an exception (no body yet, mid-navigation) counts as not ready
            while not value(
                f"(() => {{ try {{ return Boolean({ready}); }} catch (e) {{ return false; }} }})()"
            ):
                if time.monotonic() > deadline:
                    raise BrowserError(f"{url}: {ready} not true within {timeout_s:g} s")
                time.sleep(0.1)
            return value(expression)
        finally:
            os.close(to_chrome_w)
            os.close(from_chrome_r)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
