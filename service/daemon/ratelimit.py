"""A logger wrapper that logs at most one message per key and interval."""

from __future__ import annotations

import logging
import time
from typing import Any

__all__ = ["RateLimitedLog"]


class RateLimitedLog:
    """Log at most one message per ``interval_s`` per key, counting what it suppressed."""

    def __init__(self, logger: logging.Logger, interval_s: float = 5.0):
        self.logger = logger
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def warning(self, key: str, msg: str, *args: Any) -> bool:
        """Log ``msg % args`` under ``key`` unless one was logged less than interval_s ago."""
        now = time.monotonic()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        n = self._suppressed.pop(key, 0)
        self._last[key] = now
        suffix = f" ({n} similar suppressed)" if n else ""
        self.logger.warning(msg + suffix, *args)
        return True
