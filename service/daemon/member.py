"""The daemon as a member of a monitor group (``[group]``, docs/design.md, "Monitor
groups"): its group token, the other members' tokens, the summaries of the units each
member published outputs for (its own on ``monitor/{station}/{shard}/outputs``), and what
ownership changes mean for the pipeline (a released unit's period ends and its stream state
is forgotten; a unit with measurements but no outputs from its owner is ``unmonitored``).
The ownership rules themselves are ``service.daemon.group.MonitorGroup``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from service.config import GroupSettings
from service.daemon.group import GROUP_TOKENS, OUTPUTS_KEY, MonitorGroup, group_token
from service.daemon.intake import MAX_ACTUATORS, Intake
from service.daemon.monitoring import MonitorStage
from service.daemon.outputs import Outputs

__all__ = ["GroupMember"]

log = logging.getLogger("servowatch.daemon")


class GroupMember:
    """Member ``station/shard`` of the group of ``config``; ``submit`` is the intake's queue
    (``MonitorGroup`` feeds it the messages of the units this member owns)."""

    def __init__(
        self,
        config: GroupSettings,
        station: str,
        shard: str,
        submit: Callable[[str, bytes, float], Any],
        max_bytes: int,
    ) -> None:
        self.config = config
        self.station, self.shard = station, shard
        self.group = MonitorGroup(
            config.name, f"{station}/{shard}", submit, takeover_s=config.takeover_s,
            unmonitored_s=config.unmonitored_s, max_units=MAX_ACTUATORS, max_bytes=max_bytes,
            stations=tuple(config.stations),
        )  # fmt: skip
        self._token = None
        self._session: Any = None
        self._published: dict[str, int] = {}  # meas key -> its ``published`` at the last summary
        self._summary_at = 0.0
        #: how often the outputs summary goes out [s]
        self.summary_s = min(1.0, config.unmonitored_s / 4)
        self._join_timer: threading.Timer | None = None
        self.errors = 0

    def declare(self, session: Any) -> list[Any]:
        """Hold this member's group token, watch the others', own after ``join_s``; returns
        the Zenoh entities declared."""
        import zenoh

        g = self.group
        zid = str(session.info.zid())
        self._token = session.liveliness().declare_token(
            group_token(self.station, self.shard, g.name, zid)
        )

        def on_member(sample) -> None:
            try:
                who = g.member_of_token(str(sample.key_expr))
                if who is not None:
                    g.member_event(who[0], sample.kind == zenoh.SampleKind.PUT, who[1])
            except Exception:
                self.errors += 1

        decl = [
            self._token,
            session.liveliness().declare_subscriber(
                GROUP_TOKENS.format(group=g.name), on_member, history=True
            ),
            # each member's summary of its outputs: a unit with meas but none from its
            # owner is unmonitored
            session.declare_subscriber(
                OUTPUTS_KEY.format(station="*", shard="*"), self._on_outputs
            ),
        ]
        self._session = session
        self._join_timer = threading.Timer(self.config.join_s, g.join)
        self._join_timer.daemon = True
        self._join_timer.start()
        log.info("member %s of monitor group %s, owning after %.1f s", g.me, g.name,
                 self.config.join_s)  # fmt: skip
        return decl

    def _on_outputs(self, sample) -> None:
        """A member's summary: the units it published outputs for since its last one. The
        member is the key's (``monitor/{station}/{shard}/outputs``, which only that daemon's
        certificate may put), whatever the payload says."""
        try:
            parts = str(sample.key_expr).split("/")
            if len(parts) != 4 or parts[0] != "monitor" or parts[3] != "outputs":
                return
            member = f"{parts[1]}/{parts[2]}"
            raw = sample.payload.to_bytes()
            units = json.loads(raw)["units"] if len(raw) <= 1 << 20 else None
            if not isinstance(units, list):
                raise ValueError("units: not a list")
            now = time.monotonic()
            for u in units[: 4 * MAX_ACTUATORS]:
                if isinstance(u, str) and u.count("/") == 1:
                    self.group.output_seen(f"fleet/{u}/meas", now, member)
        except Exception:
            self.errors += 1

    def publish_outputs(self, now: float, intake: Intake) -> None:
        """Every ``summary_s``: put the units this member published outputs for since its
        last summary (the worker's thread: it owns ``intake.actuators``)."""
        if self._session is None or now - self._summary_at < self.summary_s:
            return
        self._summary_at = now
        units = []
        for key, st in list(intake.actuators.items()):
            if st.published > self._published.get(key, 0):
                units.append(st.name)
            self._published[key] = st.published
        if len(self._published) > 2 * MAX_ACTUATORS:  # units gone from the table
            self._published = {k: v for k, v in self._published.items() if k in intake.actuators}
        try:
            self._session.put(
                OUTPUTS_KEY.format(station=self.station, shard=self.shard),
                json.dumps({"units": units}).encode(),
            )
        except Exception as e:
            self.errors += 1
            log.debug("outputs summary: %s", e)

    def leave(self) -> None:
        """Leave the group first at a stop: the others take the units over while this
        member drains what it has (overlap, not loss)."""
        if self._join_timer is not None:
            self._join_timer.cancel()
        if self._token is not None:
            with contextlib.suppress(Exception):
                self._token.undeclare()

    def release_units(self, intake: Intake, monitor: MonitorStage, outputs: Outputs) -> list[str]:
        """Units another member took over: their operating period ends and their stream state
        is forgotten, so one that comes back starts afresh (no false gaps, a new period); the
        monitor re-initialises itself on the time gap. Returns their names."""
        g = self.group
        g.sweep(time.monotonic())
        out = []
        for key in g.pop_released():
            st = intake.actuators.get(key)
            if st is None:
                continue
            outputs.end_period(monitor.row_of(key))
            outputs.service_event(st, "released", st.last_t)  # at its last sample, as "silent"
            intake.forget(key)
            out.append(st.name)
        return out

    def check_unmonitored(self, now: float, silence_s: float, intake: Intake, outputs: Outputs):
        """Units with measurements but no member's output for ``unmonitored_s``: the
        ``unmonitored`` event (and ``monitored`` when outputs resume); returns the new ones."""
        new, back = self.group.check_unmonitored(now, silence_s)
        for key, owner, age in new:
            log.warning(
                "%s unmonitored: no health output for %.1f s (its owner in this member's view: "
                "%s)", key, age, owner,
            )  # fmt: skip
            outputs.group_event(
                key, "unmonitored", {"owner": owner, "for_s": round(age, 3)},
                intake.actuators.get(key),
            )  # fmt: skip
        for key in back:
            log.info("%s monitored again", key)
            outputs.group_event(key, "monitored", None, intake.actuators.get(key))
        return [k for k, _, _ in new]

    def status(self, released: list[str]) -> dict[str, Any]:
        """The group part of the status; ``released``: units this member monitored that
        another one has now."""
        return {**self.group.status(), "released_units": released}
