"""A monitor group: daemons that share the fleet's actuators among themselves.

Every member holds a liveliness token ``monitor/{station}/{shard}/group/{group}/{zid}`` (the
session id tells two incarnations of one member apart, so the old token's late removal never
removes a restarted member) and watches the others'. Each actuator belongs to one live member, chosen by rendezvous hashing (highest
random weight: the member whose hash of (member, unit) is highest): every member computes
the same owner from the same member set, with no coordination message, and when a member
leaves only its own units move, spread over the others; when one joins it takes about 1/N
of every other member's units and nothing else moves.

A member keeps the last ``takeover_s`` seconds of the messages of units it does not own.
When a unit becomes its own (its owner's token vanished: a crash, a lost link, a stop), it
feeds those first, so the samples the old owner received but may not have processed are not
lost to the new one. Until it has joined, a member keeps everything it receives, so a member
that starts (or restarts) loses nothing of the units the others hand it. Messages of owned
units pass straight on. Ownership and the hand-over are decided under one lock, so a
hand-over never reorders a unit's messages.

A member also watches the group's work: every unit whose measurements keep arriving must
show outputs **from its owner** at least every ``unmonitored_s`` seconds. Each member puts,
on its own key ``monitor/{station}/{shard}/outputs`` (which the router lets only that
daemon's certificate put), the units it published outputs for; what another member, or any
other identity, publishes on a unit's ``health`` key does not count. A unit whose owner shows
none (a member that holds a token but processes nothing, or a unit released to nobody) is
**unmonitored**: every member raises the ``unmonitored`` event and lists it in its status
until its owner's outputs resume. A member judges the units the others own (its own show to
them); a new owner has ``unmonitored_s`` from the membership change that gave it the unit,
once until it shows outputs: a member that flaps its token takes no fresh grace each time.

Membership is confined to this member's station and the ``stations`` the configuration
lists: a token of another station (a valid certificate of station B, holding its own token)
is ignored and counted (``foreign_tokens``).

Memory is bounded: at most ``max_units`` held units, ``max_held`` messages each, no payload
larger than ``max_bytes`` (the owner counts those), and ``sweep`` drops what has aged out.

Lock order: the group's lock, then the daemon's queue (``submit``; on a full queue its drop
counter takes the daemon's lock). Nothing calls into the group while holding the daemon's lock.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from service.wire import messages as m

__all__ = ["owner_of", "group_token", "GROUP_TOKENS", "OUTPUTS_KEY", "MonitorGroup"]

GROUP_TOKEN = "monitor/{station}/{shard}/group/{group}/{zid}"
GROUP_TOKENS = "monitor/*/*/group/{group}/*"
#: where a member says which units it published outputs for (its own key)
OUTPUTS_KEY = "monitor/{station}/{shard}/outputs"


def group_token(station: str, shard: str, group: str, zid: str) -> str:
    """The liveliness token a member of ``group`` holds (``zid``: its session id)."""
    return GROUP_TOKEN.format(station=station, shard=shard, group=group, zid=zid)


def _weight(member: str, unit: str) -> int:
    h = hashlib.blake2b(f"{member}\x00{unit}".encode(), digest_size=8).digest()
    return int.from_bytes(h, "big")


def owner_of(unit: str, members: Iterable[str]) -> str | None:
    """The member that owns ``unit`` (``AIRCRAFT/ACTUATOR``): the highest rendezvous weight,
    ties (not met in practice) broken by name; None without members."""
    best: tuple[int, str] | None = None
    for mem in members:
        w = (_weight(mem, unit), mem)
        if best is None or w > best:
            best = w
    return None if best is None else best[1]


def _unit_of_key(key: str) -> str | None:
    try:
        return "/".join(m.parse_meas_key(key))
    except m.MessageError:
        return None


class MonitorGroup:
    """Ownership of one member (``me``, ``station/shard``) of group ``name``.

    ``submit(key, payload, t_recv)`` is the daemon's queue; ``admit`` is called for every
    received message instead of it. Until ``join()`` (the daemon calls it ``join_s`` after
    declaring its token and subscriber, when the other members' tokens have arrived) nothing
    is owned and everything is held, so a starting member never monitors a unit another one
    owns."""

    def __init__(
        self,
        name: str,
        me: str,
        submit: Callable[[str, bytes, float], Any],
        takeover_s: float = 2.0,
        *,
        max_units: int = 10_000,
        max_held: int = 20_000,
        max_bytes: int = 65536,
        unmonitored_s: float = 5.0,
        stations: tuple[str, ...] = (),
    ) -> None:
        self.name = name
        self.me = me
        self.submit = submit
        self.takeover_s = float(takeover_s)
        self.max_units = int(max_units)
        self.max_held = int(max_held)
        self.max_bytes = int(max_bytes)
        self.members: set[str] = {me}
        self._incarnations: dict[str, set[str]] = {}  # member -> session ids of its tokens
        self._released_keys: list[str] = []  # units that became another member's, for the daemon
        self.joined = False
        self._lock = threading.Lock()
        self._owner: dict[str, str | None] = {}  # meas key -> owner, for the current members
        self._held: dict[str, deque] = {}  # meas key -> (payload, t_recv) of a unit not owned
        self.not_held = 0  # others' messages not kept (too many units, oversize)
        self.takeovers = 0  # units that became this member's after it had joined
        self.released = 0  # units that became another member's
        self.handed_over = 0  # held messages fed on a takeover
        self.changes = 0  # membership changes seen
        self.unmonitored_s = float(unmonitored_s)
        self._joined_at = 0.0  # time.monotonic() of the join
        self._changed_at = 0.0  # time.monotonic() of the last membership change
        self._last_meas: dict[str, float] = {}  # meas key -> last arrival (every unit)
        self._first_meas: dict[str, float] = {}  # meas key -> first arrival
        self._last_output: dict[str, float] = {}  # meas key -> last output of any member
        self._out_by: dict[tuple[str, str], float] = {}  # (meas key, member) -> its last output
        # (meas key, owner) -> start of that owner's grace (renewed by a change only once it
        # showed outputs since: a member that flaps its token gets no fresh grace each time)
        self._grace: dict[tuple[str, str], float] = {}
        self.stations = frozenset({me.split("/")[0], *stations})
        self.foreign_tokens = 0  # group tokens of stations not in ``stations``
        self.foreign_outputs = 0  # outputs summaries of non-members
        self._unmonitored: dict[str, dict[str, Any]] = {}  # meas key -> owner, since [wall s]
        self.unmonitored_events = 0

    # -- ownership ------------------------------------------------------------------------
    def _owner_of_key(self, key: str) -> str | None:
        o = self._owner.get(key, "")
        if o == "":
            unit = _unit_of_key(key)
            o = None if unit is None else owner_of(unit, self.members)
            self._owner[key] = o
        return o

    def owns_key(self, key: str) -> bool:
        """Whether this member monitors the unit of meas key ``key`` now (a key that names
        no unit passes, so the daemon counts it as bad input)."""
        with self._lock:
            return self.joined and self._owner_of_key(key) in (self.me, None)

    # -- the daemon's inflow --------------------------------------------------------------
    def admit(self, key: str, payload: bytes, t_recv: float) -> None:
        """A received message: to the daemon's queue if its unit is ours (or it names no
        unit: the daemon counts it as bad input), else held."""
        with self._lock:
            owner = self._owner_of_key(key)
            if owner is not None and (
                key in self._last_meas or len(self._last_meas) < self.max_units
            ):
                self._last_meas[key] = t_recv
                self._first_meas.setdefault(key, t_recv)
            if owner is None or (self.joined and owner == self.me):
                self.submit(key, payload, t_recv)
                return
            if len(payload) > self.max_bytes:  # its owner counts it as oversize
                self.not_held += 1
                return
            q = self._held.get(key)
            if q is None:
                if len(self._held) >= self.max_units:
                    self.not_held += 1
                    return
                q = self._held[key] = deque(maxlen=self.max_held)
            q.append((payload, t_recv))
            if self.joined:  # before the join everything is kept (start-up hand-over)
                while q and t_recv - q[0][1] > self.takeover_s:
                    q.popleft()

    def sweep(self, now: float) -> None:
        """Drop held messages older than ``takeover_s`` (``now``: time.monotonic()), and the
        units left with none: a unit that stopped publishing holds nothing for long."""
        with self._lock:
            if not self.joined:
                return
            for key in list(self._held):
                q = self._held[key]
                while q and now - q[0][1] > self.takeover_s:
                    q.popleft()
                if not q:
                    del self._held[key]

    def output_seen(self, key: str, t: float, member: str) -> None:
        """``member`` (``station/shard``, from the key of its outputs summary, which only its
        certificate may put) published outputs of the unit of meas key ``key`` at ``t``
        (monotonic). Only a member's word counts, and only for the units it owns."""
        with self._lock:
            if member not in self.members:
                self.foreign_outputs += 1
                return
            if key in self._last_meas:
                self._last_output[key] = t
                self._out_by[(key, member)] = t

    def check_unmonitored(
        self, now: float, live_s: float
    ) -> tuple[list[tuple[str, str | None, float]], list[str]]:
        """Units that became unmonitored, as (meas key, owner, seconds without output), and
        those that are monitored again (outputs resumed, or the unit fell silent: nothing to
        monitor). A unit counts while its measurements arrived within ``live_s``."""
        new: list[tuple[str, str | None, float]] = []
        back: list[str] = []
        with self._lock:
            if not self.joined:
                return new, back
            for key, last in list(self._last_meas.items()):
                if now - last > live_s:
                    for d in (self._last_meas, self._first_meas, self._last_output):
                        d.pop(key, None)
                    for d2 in (self._out_by, self._grace):
                        for k2 in [k2 for k2 in d2 if k2[0] == key]:
                            del d2[k2]
                    if self._unmonitored.pop(key, None) is not None:
                        back.append(key)
                    continue
                # this member's own units are judged by the others (it knows it processes
                # them; its stall shows to them); another owner's by its own outputs only
                owner = self._owner_of_key(key)
                if owner is None or owner == self.me:
                    ref = now
                else:
                    out = self._out_by.get((key, owner))
                    # its grace: from the unit's start, the change that gave it the unit or
                    # this member's join; a later change renews it only if it showed outputs
                    # since the grace began
                    g0 = self._grace.get((key, owner))
                    if g0 is None:
                        g0 = self._grace[(key, owner)] = max(
                            self._first_meas[key], self._changed_at
                        )
                    g0 = max(g0, self._joined_at)
                    ref = g0 if out is None else max(out, g0)
                if now - ref > self.unmonitored_s:
                    if key not in self._unmonitored:
                        self._unmonitored[key] = {
                            "owner": owner,
                            "since": time.time() - (now - ref),
                        }
                        self.unmonitored_events += 1
                        new.append((key, owner, now - ref))
                elif self._unmonitored.pop(key, None) is not None:
                    back.append(key)
        return new, back

    def pop_released(self) -> list[str]:
        """The meas keys that became another member's since the last call (the daemon ends
        their periods and forgets their stream state, so a unit that comes back starts
        afresh)."""
        with self._lock:
            out, self._released_keys = self._released_keys, []
            return out

    # -- membership -----------------------------------------------------------------------
    def join(self) -> None:
        """Start owning: the units that are ours now are fed their held messages."""
        with self._lock:
            self.joined = True
            self._joined_at = time.monotonic()
            self._reassign(count=False)

    def member_event(
        self, member: str, present: bool, zid: str = "", now: float | None = None
    ) -> None:
        """Token ``zid`` of ``member`` appeared (``present``) or vanished (``now``:
        time.monotonic() of the change, by default the present). A member is present while
        any of its tokens is; this member itself always is."""
        with self._lock:
            if member == self.me:
                return
            zids = self._incarnations.setdefault(member, set())
            (zids.add if present else zids.discard)(zid)
            now_present = bool(zids)
            if not zids:
                del self._incarnations[member]
            if now_present == (member in self.members):
                return
            (self.members.add if now_present else self.members.discard)(member)
            self.changes += 1
            self._changed_at = time.monotonic() if now is None else now
            before = dict(self._owner)
            self._owner.clear()
            self._renew_grace()
            if not self.joined:
                return
            self._reassign(count=True, before=before)

    def _renew_grace(self) -> None:
        """Under the lock, at a membership change: a unit's new owner gets a grace from now,
        unless it already had one and showed no outputs since (a flapping member)."""
        for key in self._last_meas:
            o = self._owner_of_key(key)
            if o is None or o == self.me:
                continue
            g0, out = self._grace.get((key, o)), self._out_by.get((key, o))
            if g0 is None or (out is not None and out > g0):
                self._grace[(key, o)] = self._changed_at

    def _reassign(self, count: bool, before: dict[str, str | None] | None = None) -> None:
        """Under the lock: feed the held messages of every unit that is ours now, count the
        units that moved."""
        now = time.monotonic()
        for key in list(self._held):
            if self._owner_of_key(key) != self.me:
                continue
            q = self._held.pop(key)
            # at the join: everything since the start; later: the last takeover_s
            fresh = [(p, t) for p, t in q if not count or now - t <= self.takeover_s]
            for p, t in fresh:
                self.submit(key, p, t)
            self.handed_over += len(fresh)
            if count:
                self.takeovers += 1
        if before:
            for key, o in before.items():
                if o == self.me and self._owner_of_key(key) != self.me:
                    self.released += 1
                    self._released_keys.append(key)

    def member_of_token(self, token_key: str) -> tuple[str, str] | None:
        """(``station/shard``, session id) of a group token key, None when it is not one of
        this group's."""
        parts = token_key.split("/")
        if len(parts) != 6 or parts[0] != "monitor" or parts[3] != "group":
            return None
        if parts[4] != self.name:
            return None
        if parts[1] not in self.stations:  # another station's daemon: not of this group
            with self._lock:
                self.foreign_tokens += 1
            return None
        return f"{parts[1]}/{parts[2]}", parts[5]

    def status(self) -> dict[str, Any]:
        """The group part of the daemon's status."""
        with self._lock:
            held = {k: len(q) for k, q in self._held.items() if q}
            return {
                "name": self.name,
                "me": self.me,
                "joined": self.joined,
                "members": sorted(self.members),
                "takeovers": self.takeovers,
                "released": self.released,
                "handed_over": self.handed_over,
                "membership_changes": self.changes,
                "held_units": len(held),
                "held_messages": sum(held.values()),
                "not_held": self.not_held,
                "unmonitored_s": self.unmonitored_s,
                "unmonitored": {
                    "/".join(k.split("/")[1:3]): dict(v)
                    for k, v in sorted(self._unmonitored.items())
                },
                "unmonitored_events": self.unmonitored_events,
                "stations": sorted(self.stations),
                "foreign_tokens": self.foreign_tokens,
                "foreign_outputs": self.foreign_outputs,
            }
