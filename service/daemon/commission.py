"""Optional auto-commissioning (``[prognostics] auto_commission_s``, off by default).

An actuator without a baseline in the store is watched from its first sample. Its raw
samples are kept for ``duration_s`` of sample time. The stretch counts as healthy-looking
when no alarm flag is raised in any output row and at least ``min_in_band`` of the rows have
their NIS inside the two-sided 95 % chi-square band; an alarm restarts the collection. A
healthy-looking stretch is calibrated (``service.monitor.calibration.calibrate``) in a background
thread, recorded as the actuator's baseline version 1 (source ``auto-commissioning``) and
the actuator is moved to it from its next sample. The risk: a unit that is already degraded
becomes its own baseline (docs/prognostics.md, "Auto-commissioning").
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from service.monitor import HEALTH_KEYS, RES_KEYS, Baseline, MonitorFleet
from service.prognostics.indicators import nis_band
from service.wire import messages as m

__all__ = ["Commissioner"]

log = logging.getLogger("servowatch.commission")

_ALARM_COLS = [j for j, k in enumerate(HEALTH_KEYS) if k.startswith("alarm_")]
_NIS, _DOF = RES_KEYS.index("nis"), RES_KEYS.index("nis_dof")
_WIRE = {k: m.CHANNELS.index(k) for k in ("x_cmd", "i", "x_s", "x_j", "p1", "p2")}


class _Collect:
    def __init__(self) -> None:
        self.t: list[np.ndarray] = []
        self.ch: list[np.ndarray] = []
        self.rows = 0
        self.in_band = 0

    def span(self) -> float:
        return float(self.t[-1][-1] - self.t[0][0]) if self.t else 0.0


class Commissioner:
    """Collects, judges and calibrates the first data of uncommissioned actuators of
    ``fleet``; records their baselines in the store at ``store_url`` and moves them to it,
    telling the outputs by ``retrack(row, c_lk0=, info=)`` (``FanOut.retrack``)."""

    def __init__(
        self,
        fleet: MonitorFleet,
        store_url: str,
        retrack: Callable[..., None],
        duration_s: float,
        min_in_band: float,
    ) -> None:
        if not duration_s > 0:
            raise ValueError("auto_commission_s must be > 0")
        self.fleet = fleet
        self.store_url = store_url
        self.retrack = retrack
        self.duration_s = float(duration_s)
        self.min_in_band = float(min_in_band)
        self._col: dict[str, _Collect] = {}
        self._busy: set[str] = set()
        self._ready: list[tuple[str, Baseline, int]] = []
        self._lock = threading.Lock()
        self.commissioned: list[str] = []
        self.rejected: dict[str, int] = {}  # key -> restarts after an alarm or a bad NIS

    def feed(self, parts: list, rows: Any, ks: np.ndarray) -> None:
        """One tick of the daemon: ``parts`` its accepted inputs, ``rows`` the outputs of the
        samples of bank rows ``ks``. Applies finished calibrations first (worker thread)."""
        with self._lock:
            ready, self._ready = self._ready, []
        for key, base, version in ready:
            self._apply(key, base, version)
        fleet = self.fleet
        owner = ks[rows.index] if len(rows.index) else ks[:0]
        for _st, key, a, j0, _ in parts:
            if fleet.versions.get(key) is not None or key in self._busy:
                continue
            c = self._col.setdefault(key, _Collect())
            sel = owner == fleet.ids[key]
            h, r = rows.health[sel], rows.res[sel]
            if len(h) and (h[:, _ALARM_COLS] > 0.5).any():
                self._restart(key)
                continue
            c.t.append(np.asarray(a.t[j0:], float))
            c.ch.append(np.asarray(a.values[j0:], float))
            dof = r[:, _DOF].astype(int)
            ok = dof > 0
            lo, hi = nis_band(dof[ok])
            c.rows += int(ok.sum())
            c.in_band += int(((r[ok, _NIS] >= lo) & (r[ok, _NIS] <= hi)).sum())
            if c.span() >= self.duration_s:
                del self._col[key]
                if c.rows == 0 or c.in_band / c.rows < self.min_in_band:
                    self._restart(key)
                    continue
                self._busy.add(key)
                threading.Thread(
                    target=self._calibrate, args=(key, c), name="servowatch-commission",
                    daemon=True,
                ).start()  # fmt: skip

    def _restart(self, key: str) -> None:
        self._col.pop(key, None)
        self.rejected[key] = self.rejected.get(key, 0) + 1

    def _calibrate(self, key: str, c: _Collect) -> None:
        from service.monitor.calibration import calibrate
        from service.store import open_store

        name = "/".join(m.parse_meas_key(key))
        try:
            t = np.concatenate(c.t)
            ch = np.concatenate(c.ch)
            meas = {"t": t, **{k: ch[:, j] for k, j in _WIRE.items()}}
            base = calibrate(meas, self.fleet.config.model)
            base = base.model_copy(update={"source": f"auto-commissioning of {name}"})
            figures = {"samples": int(len(t)), "duration_s": float(t[-1] - t[0]),
                       "nis_in_band": c.in_band / c.rows}  # fmt: skip
            with open_store(self.store_url) as s:
                rec = s.add_baseline(name, base.model_dump(), "auto-commissioning", figures)
            with self._lock:
                self._ready.append((key, base, rec.version))
            log.info("%s auto-commissioned: baseline version %d", name, rec.version)
        except Exception as e:
            log.error("auto-commissioning of %s failed: %s", name, e)
            with self._lock:
                self._busy.discard(key)

    def _apply(self, key: str, base: Baseline, version: int) -> None:
        fleet = self.fleet
        fleet.rebase(key, base, version)
        row = fleet.ids[key]
        info = {"commissioned": True, "baseline_version": version}
        self.retrack(row, c_lk0=base.c_lk, info=info)
        self._busy.discard(key)
        self.commissioned.append(key)
