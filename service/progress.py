"""Terminal progress for long runs (tqdm): a single refreshed line on a TTY, silent otherwise."""

from __future__ import annotations

import sys
from typing import TextIO

from tqdm import tqdm

__all__ = ["Progress"]

_STEPS = 1000  # resolution of the bar (fractions are rounded to 0.1 %)


class Progress:
    """Callable ``progress(fraction)`` that draws ``label  42%|####      | [00:03<00:04]`` on
    stderr through tqdm.

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
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = force or (hasattr(self.stream, "isatty") and self.stream.isatty())
        self._bar = tqdm(
            total=_STEPS,
            desc=label,
            file=self.stream,
            disable=not self.enabled,
            mininterval=1.0 / max_hz,
            ncols=len(label) + width + 40,
            bar_format="{desc} {percentage:5.1f}%|{bar}| [{elapsed}<{remaining}]",
            leave=True,
        )

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        n = int(round(min(max(fraction, 0.0), 1.0) * _STEPS))
        if n > self._bar.n:
            self._bar.update(n - self._bar.n)

    def done(self) -> None:
        """Finish the line (call once at the end)."""
        if self.enabled:
            self(1.0)
        self._bar.close()
