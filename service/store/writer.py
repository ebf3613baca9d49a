"""The daemon's store writer: closed periods and alarm events written off the sample path.

``submit(periods, alarms)`` only appends to a queue; a background thread with its own
connection writes each period in its own transaction (``HealthStore.add_periods([p])``), so
a killed daemon leaves whole periods or none, and the alarm events of a batch in one more.
The thread also keeps a small cache per actuator (stored period count, last RUL) for the
daemon's status, refreshed after each write and every ``refresh_s``.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from typing import Any

from service.store.health import open_store
from service.store.records import AlarmEvent, Period

__all__ = ["StoreWriter"]

log = logging.getLogger("servowatch.store")

_STOP = object()


class StoreWriter:
    """Background writer of periods and alarm events to the store at ``url``."""

    def __init__(self, url: str, refresh_s: float = 60.0) -> None:
        self.url = url
        self.refresh_s = float(refresh_s)
        self._q: queue.Queue = queue.Queue()
        self._info: dict[str, dict[str, Any]] = {}
        self.written = 0  # periods written (new)
        self.errors = 0
        self.failure: str | None = None
        with open_store(url) as s:  # fail fast (bad path, wrong schema) in the caller
            self._load(s)
        self._thread = threading.Thread(target=self._run, name="servowatch-store", daemon=True)
        self._thread.start()

    def submit(self, periods: list[Period], alarms: list[AlarmEvent]) -> None:
        """Queue periods and alarm events for writing (never blocks)."""
        if periods or alarms:
            self._q.put((list(periods), list(alarms)))

    def info(self, actuator: str) -> dict[str, Any]:
        """Cached ``{"periods": n, "rul": dict | None, "last_ratio": float | None}`` of
        ``actuator`` ("AC/ACT"): its stored periods, RUL and latest observable C_Lk ratio in
        life order (the fleet view's, ``fleet_summary``)."""
        d = self._info.get(actuator)
        return dict(d) if d else {"periods": 0, "rul": None, "last_ratio": None}

    @property
    def pending(self) -> int:
        """Batches waiting to be written."""
        return self._q.qsize()

    def close(self, timeout: float = 30.0) -> None:
        """Write what is queued, then stop the thread."""
        self._q.put(_STOP)
        self._thread.join(timeout)

    def _load(self, store: Any) -> None:
        self._info = {
            r["actuator"]: {"periods": r["periods"], "rul": r["rul"], "last_ratio": r["last_ratio"]}
            for r in store.fleet_summary()
        }

    def _run(self) -> None:
        try:
            store = open_store(self.url)
        except Exception as e:
            self.failure = str(e)
            log.error("health store %s: %s", self.url, e)
            return
        last = time.monotonic()
        with store:
            while True:
                try:
                    item = self._q.get(timeout=max(self.refresh_s, 0.1))
                except queue.Empty:
                    item = None
                if item is _STOP:
                    return
                try:
                    if item is not None:
                        periods, alarms = item
                        for p in periods:  # one transaction each: whole periods or none
                            self.written += store.add_periods([p])
                        if alarms:
                            store.add_alarms(alarms)
                    if item is not None or time.monotonic() - last >= self.refresh_s:
                        self._load(store)
                        last = time.monotonic()
                except Exception as e:  # a store failure must not stop the daemon
                    self.errors += 1
                    self.failure = str(e)
                    log.error("health store write failed: %s", e)
