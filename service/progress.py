"""Terminal progress for long runs: a single refreshed line on a TTY, silent otherwise."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


class Progress:
    """Callable ``progress(fraction)`` that draws ``label [#####     ]  42 %`` on stderr.

    Draws at most ``max_hz`` times a second, only when the stream is a terminal (or
    ``force``), so ``--json`` output and logs stay clean.
    """

    def __init__(
        self,
        label: str,
        *,
        stream: TextIO | None = None,
        force: bool = False,
        max_hz: float = 10.0,
        width: int = 30,
    ) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = force or (hasattr(self.stream, "isatty") and self.stream.isatty())
        self.min_dt = 1.0 / max_hz
        self.width = width
        self._last = 0.0
        self._t0 = time.perf_counter()
        self._drawn = False

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if fraction < 1.0 and now - self._last < self.min_dt:
            return
        self._last = now
        f = min(max(fraction, 0.0), 1.0)
        n = int(round(f * self.width))
        bar = "#" * n + " " * (self.width - n)
        self.stream.write(f"\r{self.label} [{bar}] {100 * f:5.1f} %  {now - self._t0:6.1f} s")
        self.stream.flush()
        self._drawn = True

    def done(self) -> None:
        """Finish the line (call once at the end)."""
        if self.enabled and self._drawn:
            self(1.0)
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False
