"""Live state of the monitoring daemons for the fleet page: a thread asks every daemon's
status queryable (``monitor/*/*/status``, the same query as ``servowatch status``) every
``period_s`` and keeps the last answer, slimmed to what the page shows. The page's HTTP
threads only read that copy, so a slow or absent daemon never holds up a request."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from service.edge.status import STATUS_SELECTOR, query_status

__all__ = ["LiveStatus", "slim"]


def slim(daemons: dict[str, dict[str, Any]], queried_s: float) -> dict[str, Any]:
    """The page's live JSON from ``query_status``'s ``{key: status}``: one entry per daemon
    (station, shard, state, counters, latency p99 [ms], silent units, raised alarms) and per
    unit ``AIRCRAFT/ACTUATOR`` the daemon that monitors it with that unit's samples, silence,
    bad/dropped/missed counts and raised alarm kinds."""
    from service.edge.status import believed, name_of_key

    out_d: list[dict[str, Any]] = []
    units: dict[str, dict[str, Any]] = {}
    for key, st in sorted(daemons.items()):
        if not isinstance(st, dict) or "malformed" in st or "error" in st:
            why = st.get("malformed") or st.get("error") if isinstance(st, dict) else None
            out_d.append({"key": key, "state": "malformed", "error": why})
            continue
        if not believed(key, st):  # claims another daemon's name: told apart, not believed
            out_d.append({"key": key, "name": name_of_key(key), "state": "name_mismatch",
                          "claims": st.get("name_mismatch")})  # fmt: skip
            continue
        name = f"{st.get('station')}/{st.get('shard')}"
        acts = st.get("actuators") or {}
        out_d.append(
            {
                "key": key,
                "name": name,
                "state": st.get("state"),
                "model": st.get("model"),
                "uptime_s": st.get("uptime_s"),
                "units": len(acts),
                "samples": st.get("samples"),
                "dropped": st.get("dropped"),
                "bad": st.get("bad"),
                "missed": st.get("missed"),
                "latency_p99_ms": (st.get("latency_ms") or {}).get("p99"),
                "log_failure": st.get("log_failure"),
                "silent": list(st.get("silent") or []),
                "unmonitored": sorted((st.get("group") or {}).get("unmonitored") or {}),
                # what the reply check left out (service.edge.status): named, not shown
                "bad_fields": list(st.get("bad_fields") or []),
                "bad_units": sorted(st.get("bad_units") or {}),
            }
        )
        for a in acts.values():
            if not isinstance(a, dict) or "aircraft" not in a or "actuator" not in a:
                continue
            unit = f"{a['aircraft']}/{a['actuator']}"
            units[unit] = {
                "daemon": name,
                "samples": a.get("samples"),
                "silent": bool(a.get("silent")),
                "bad": a.get("bad"),
                "dropped": a.get("dropped"),
                "missed": a.get("missed"),
                "alarms": sorted({str(x.get("kind")) for x in a.get("alarms") or []}),
            }
    # a unit that any member reports unmonitored (measurements, no member's output) is shown
    # so, whoever last listed it
    for key, st in daemons.items():
        g = st.get("group") if believed(key, st) else None
        for unit, u in ((g or {}).get("unmonitored") or {}).items():
            entry = units.setdefault(unit, {"daemon": None})
            entry["unmonitored"] = True
            entry["owner"] = (u or {}).get("owner")
    return {"enabled": True, "queried_s": queried_s, "daemons": out_d, "units": units}


class LiveStatus:
    """Polls the daemons' status in a daemon thread; ``snapshot()`` is the last ``slim``
    answer (with ``age_s``), or says why there is none.

    ``connect`` opens the Zenoh session. The thread calls it, and again each period until it
    succeeds, so a page started before its router (or across a router restart at start-up)
    shows the error and picks the live status up once the router answers. A failed query
    clears the units: stale "receiving" cells would say more than is known."""

    def __init__(
        self, connect: Callable[[], Any], period_s: float = 5.0, timeout_s: float = 2.0
    ) -> None:
        self.connect = connect
        self.session: Any = None
        self.period_s = max(float(period_s), 0.5)
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._last: dict[str, Any] = {
            "enabled": True,
            "queried_s": None,
            "daemons": [],
            "units": {},
        }
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="servowatch-web-live", daemon=True)

    def start(self) -> LiveStatus:
        self._thread.start()
        return self

    def _failed(self, error: str) -> None:
        with self._lock:
            self._last = {**self._last, "daemons": [], "units": {}, "error": error}

    def poll_once(self) -> None:
        """Open the session if it is not open yet, then one query; the result (or its
        error) replaces the last one."""
        if self.session is None:
            try:
                self.session = self.connect()
            except Exception as e:  # SessionError (3, 4) and the like: retried next period
                self._failed(f"no Zenoh session: {e}")
                return
        try:
            daemons = query_status(self.session, self.timeout_s, STATUS_SELECTOR)
            snap = slim(daemons, time.time())
        except Exception as e:  # a closed session, a transport error: say so on the page
            self._failed(f"status query failed: {type(e).__name__}: {e}")
            return
        with self._lock:
            self._last = snap

    def _loop(self) -> None:
        while not self._stop.is_set():
            t0 = time.monotonic()
            self.poll_once()
            self._stop.wait(max(self.period_s - (time.monotonic() - t0), 0.05))

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            s = dict(self._last)
        q = s.get("queried_s")
        s["age_s"] = None if q is None else max(time.time() - q, 0.0)
        return s

    def close(self) -> None:
        """Stop the thread and close the session."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(self.timeout_s + 5.0)
        if self.session is not None:
            self.session.close()
            self.session = None
