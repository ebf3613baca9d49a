"""Monitor outputs -> log blocks, alarm events and published messages: the one fan-out that
both the daemon and the replay use, so a replay logs and publishes what the daemon did.

Per actuator, counting its outputs 1, 2, ...:

* est, residual and health are logged together for every ``log_every``-th output and for
  every output that carries an alarm event (one ``log_block`` per topic and block);
* every alarm event is logged on ``.../events``;
* est, res and health are published every ``publish_every``-th output.

Health follows ``log_every`` (as est and residual), not ``publish_every``: the log is the
record of the monitor, decimated by one setting, and each logged est row then has the health
row of the same sample; what is published is a transport choice of its own.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from service import messages as m
from service.jsonutil import event_dict, flat, jsonable
from service.monitor import EST_KEYS, HEALTH_KEYS, RES_KEYS, BankRows

__all__ = ["FanOut", "Emitted"]

log = logging.getLogger("servowatch.fanout")


@dataclass
class Emitted:
    """What :meth:`FanOut.emit` did for one actuator in one block of outputs."""

    row: int  # the actuator's bank row
    name: str  # "{aircraft}/{actuator}"
    outputs: int  # outputs of this actuator in the block
    last: int  # index in the BankRows of its latest output
    published: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)  # event dicts, in order


@dataclass
class _Target:
    aircraft: str
    actuator: str
    prefix: str  # "/fleet/{aircraft}/{actuator}/"
    outputs: int = 0
    publishers: dict[str, Any] = field(default_factory=dict)


class FanOut:
    """Turns ``BankRows`` into log blocks (``logger.log_block``), events (``logger.log``) and
    Zenoh puts on ``fleet/{ac}/{act}/{est,res,health}`` (``session``; None: no publishing).

    ``on_publish_error(exc)`` is called when a put fails (None: the error propagates).
    """

    def __init__(
        self,
        logger: Any | None,
        *,
        log_every: int = 1,
        publish_every: int = 10,
        session: Any | None = None,
        on_publish_error: Callable[[Exception], None] | None = None,
    ) -> None:
        if int(log_every) < 1 or int(publish_every) < 1:
            raise ValueError("log_every and publish_every must be >= 1")
        self.logger = logger
        self.log_every = int(log_every)
        self.publish_every = int(publish_every)
        self.session = session
        self.on_publish_error = on_publish_error
        self._targets: dict[int, _Target] = {}

    def track(self, row: int, aircraft: str, actuator: str) -> None:
        """Name the actuator of bank row ``row`` (before its first output)."""
        if row not in self._targets:
            self._targets[row] = _Target(aircraft, actuator, f"/fleet/{aircraft}/{actuator}/")

    def outputs_of(self, row: int) -> int:
        """Outputs of bank row ``row`` so far."""
        return self._targets[row].outputs

    def emit(self, rows: BankRows, ks: NDArray[np.int64]) -> list[Emitted]:
        """Log, publish and collect the events of ``rows`` (outputs of a bank update whose
        inputs belonged to bank rows ``ks``); one :class:`Emitted` per actuator, in the order
        of the bank rows."""
        idx = rows.index
        if len(idx) == 0:
            return []
        owner = ks[idx]
        has_ev = rows.events.flags()
        order = np.argsort(owner, kind="stable")
        out = []
        lg = self.logger
        for g in np.split(order, np.flatnonzero(np.diff(owner[order])) + 1):
            row = int(owner[g[0]])
            tg = self._targets[row]
            num = tg.outputs + 1 + np.arange(len(g))
            tg.outputs += len(g)
            ev = has_ev[g]
            em = Emitted(row, f"{tg.aircraft}/{tg.actuator}", len(g), int(g[-1]))
            if lg is not None:
                sel = g[(num % self.log_every == 0) | ev]
                if len(sel):
                    ts = rows.t[sel]
                    lg.log_block(tg.prefix + "est", ts, EST_KEYS, rows.est[sel])
                    lg.log_block(tg.prefix + "residual", ts, RES_KEYS, rows.res[sel])
                    lg.log_block(tg.prefix + "health", ts, HEALTH_KEYS, rows.health[sel])
            for r in g[ev].tolist():
                t_r = float(rows.t[r])
                for e in rows.events[r]:
                    d = event_dict(e)
                    if lg is not None:
                        lg.log(tg.prefix + "events", float(d.get("t") or t_r), flat(d))
                    em.events.append(d)
            if self.session is not None:
                for r in g[num % self.publish_every == 0].tolist():
                    o = rows.output(r)
                    self._publish(tg, o.t, {"est": o.est, "res": o.res, "health": o.health})
                    em.published += 1
            out.append(em)
        return out

    def _publish(self, tg: _Target, t: float, parts: dict[str, dict]) -> None:
        for leaf, d in parts.items():
            pub = tg.publishers.get(leaf)
            try:
                if pub is None:
                    tmpl = {"est": m.KEY_EST, "res": m.KEY_RES, "health": m.KEY_HEALTH}[leaf]
                    pub = tg.publishers[leaf] = self.session.declare_publisher(
                        tmpl.format(aircraft=tg.aircraft, actuator=tg.actuator)
                    )
                try:  # the monitor's outputs are finite floats: plain json.dumps
                    payload = m.encode_json({"t": t, **d})
                except ValueError:
                    payload = m.encode_json({"t": t, **jsonable(d)})
                pub.put(payload)
            except Exception as e:
                if self.on_publish_error is None:
                    raise
                self.on_publish_error(e)

    def close(self) -> None:
        """Undeclare the publishers."""
        for tg in self._targets.values():
            for pub in tg.publishers.values():
                try:
                    pub.undeclare()
                except Exception as e:  # the session may be closed already
                    log.debug("undeclare: %s", e)
            tg.publishers.clear()
