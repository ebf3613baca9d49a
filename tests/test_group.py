"""Monitor groups (``service.daemon.group``): rendezvous ownership worked through, and the
hold-and-hand-over of a unit's messages when its owner leaves."""

from __future__ import annotations

import time
from collections import Counter

from service.daemon.group import MonitorGroup, group_token, owner_of

UNITS = [f"AC{a:03d}/act{k}" for a in range(50) for k in range(8)]  # 400 units


def test_owner_is_deterministic_and_balanced():
    members = ["gA/0", "gB/0", "gC/0", "gD/0"]
    own = {u: owner_of(u, members) for u in UNITS}
    assert own == {u: owner_of(u, list(reversed(members))) for u in UNITS}  # order-free
    counts = Counter(own.values())
    assert set(counts) == set(members)
    # 400 units over 4 members: 100 each on average, binomial sd ~8.7
    assert all(60 <= n <= 140 for n in counts.values()), counts
    assert owner_of("AC1/x", []) is None


def test_only_the_leavers_units_move():
    before = ["gA/0", "gB/0", "gC/0"]
    after = ["gA/0", "gC/0"]
    moved = [u for u in UNITS if owner_of(u, before) != owner_of(u, after)]
    assert moved and all(owner_of(u, before) == "gB/0" for u in moved)
    assert len(moved) == sum(owner_of(u, before) == "gB/0" for u in UNITS)
    # a joiner takes units from every member and moves nothing else
    joined = [*before, "gD/0"]
    for u in UNITS:
        o0, o1 = owner_of(u, before), owner_of(u, joined)
        assert o1 in (o0, "gD/0")


def _key(unit: str) -> str:
    return f"fleet/{unit}/meas"


def test_hold_then_hand_over_in_order():
    got: list[tuple[str, bytes]] = []
    g = MonitorGroup("g", "gA/0", lambda k, p, t: got.append((k, p)), takeover_s=10.0)
    g.member_event("gB/0", True)
    assert g.members == {"gA/0", "gB/0"}
    mine = next(u for u in UNITS if owner_of(u, g.members) == "gA/0")
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gB/0")
    t = time.monotonic()
    g.admit(_key(mine), b"m0", t)  # before join: held, even our own
    g.admit(_key(theirs), b"t0", t)
    assert got == [] and not g.owns_key(_key(mine))
    g.join()
    assert got == [(_key(mine), b"m0")] and g.owns_key(_key(mine))
    g.admit(_key(mine), b"m1", t)
    g.admit(_key(theirs), b"t1", t)
    assert got[-1] == (_key(mine), b"m1") and len(got) == 2
    g.member_event("gB/0", False)  # gB's token vanished: its units are ours, held ones first
    assert got[2:] == [(_key(theirs), b"t0"), (_key(theirs), b"t1")]
    g.admit(_key(theirs), b"t2", t)
    assert got[-1] == (_key(theirs), b"t2")
    st = g.status()
    # one held message fed at the join, two at the takeover
    assert st["takeovers"] == 1 and st["handed_over"] == 3 and st["members"] == ["gA/0"]
    g.member_event("gB/0", True)  # back: its units go back to it
    assert not g.owns_key(_key(theirs)) and g.status()["released"] >= 1


def test_held_messages_older_than_takeover_are_dropped():
    got: list[bytes] = []
    g = MonitorGroup("g", "gA/0", lambda k, p, t: got.append(p), takeover_s=2.0)
    g.member_event("gB/0", True)
    g.join()
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gB/0")
    now = time.monotonic()
    for i, age in enumerate((9.0, 5.0, 0.2, 0.0)):  # 1.8 s of margin for a stalled thread
        g.admit(_key(theirs), bytes([i]), now - age)
    g.member_event("gB/0", False)
    assert got == [bytes([2]), bytes([3])]


def test_before_the_join_everything_is_kept():
    """A member that starts is handed its units by the others as soon as they see its token;
    it must not lose what came in before its own join, however long that took."""
    got: list[bytes] = []
    g = MonitorGroup("g", "gA/0", lambda k, p, t: got.append(p), takeover_s=0.5)
    mine = next(u for u in UNITS if owner_of(u, ["gA/0"]) == "gA/0")
    now = time.monotonic()
    for i, age in enumerate((3.0, 2.0, 1.0, 0.0)):
        g.admit(_key(mine), bytes([i]), now - age)
    g.join()
    assert got == [bytes([0]), bytes([1]), bytes([2]), bytes([3])]


def test_a_restarted_member_is_not_removed_by_its_old_token():
    g = MonitorGroup("g", "gA/0", lambda *a: None)
    g.member_event("gB/0", True, "zid-old")
    g.member_event("gB/0", True, "zid-new")  # restarted before the old token went
    g.member_event("gB/0", False, "zid-old")
    assert g.members == {"gA/0", "gB/0"}
    g.member_event("gB/0", False, "zid-new")
    assert g.members == {"gA/0"}


def test_held_memory_is_bounded():
    g = MonitorGroup("g", "gA/0", lambda *a: None, max_units=3, max_held=5, max_bytes=10)
    g.member_event("gB/0", True)
    g.join()
    theirs = [u for u in UNITS if owner_of(u, g.members) == "gB/0"][:5]
    t = time.monotonic()
    for u in theirs:
        for _ in range(8):
            g.admit(_key(u), b"x", t)
    g.admit(_key(theirs[0]), b"y" * 11, t)  # oversize: not held
    st = g.status()
    assert st["held_units"] == 3 and st["held_messages"] == 15
    assert st["not_held"] == 2 * 8 + 1
    g.sweep(t + 10.0)  # all aged out
    assert g.status()["held_units"] == 0


def test_a_key_that_names_no_unit_passes_to_the_daemon():
    got: list[str] = []
    g = MonitorGroup("g", "gA/0", lambda k, p, t: got.append(k))
    g.admit("fleet/bad key/x/meas", b"x", time.monotonic())  # before the join, too
    assert got == ["fleet/bad key/x/meas"]


def test_token_names():
    g = MonitorGroup("fleetA", "gA/0", lambda *a: None, stations=("gB",))
    tok = group_token("gB", "1", "fleetA", "abc123")
    assert tok == "monitor/gB/1/group/fleetA/abc123"
    assert g.member_of_token(tok) == ("gB/1", "abc123")
    assert g.member_of_token("monitor/gA/7/group/fleetA/abc") == ("gA/7", "abc")  # own station
    assert g.member_of_token("monitor/gB/1/group/other/abc") is None
    assert g.member_of_token("monitor/gB/1/alive") is None
    assert g.status()["foreign_tokens"] == 0


def test_a_daemon_of_another_station_cannot_join():
    """A valid certificate of station gC holds its own group token: not a member of a group
    confined to its own station and the listed ones (issue 43)."""
    for stations in ((), ("gB",)):
        g = MonitorGroup("fleetA", "gA/0", lambda *a: None, stations=stations)
        assert g.member_of_token(group_token("gC", "0", "fleetA", "z")) is None
        assert g.status()["foreign_tokens"] == 1 and g.status()["members"] == ["gA/0"]


def test_only_the_owners_outputs_keep_a_unit_monitored():
    """Outputs of a unit reported by a member that does not own it, or by a non-member,
    never mask its owner's silence; a member that flaps its token gets no fresh grace."""
    g = MonitorGroup("g", "gA/0", lambda k, p, t: None, unmonitored_s=1.0)
    now = time.monotonic()
    g.join()
    g._joined_at = now - 10.0
    g.member_event("gA/1", True, now=now - 10.0)  # the idle member, long ago
    g.member_event("gA/2", True, now=now - 10.0)  # a working member that does not own it
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gA/1")
    _stream(g, theirs, now - 3.0, now, outputs=False)
    for i in range(30):
        t = now - 3.0 + 0.1 * i
        g.output_seen(_key(theirs), t, "gA/2")  # a member's word for a unit it does not own
        g.output_seen(_key(theirs), t, "gZ/0")  # a non-member's
    new, _ = g.check_unmonitored(now, live_s=2.0)
    assert [(k, o) for k, o, _ in new] == [(_key(theirs), "gA/1")]
    assert g.status()["foreign_outputs"] == 30
    # the idle member flaps its token: each time the unit comes back to it, no new grace
    g.output_seen(_key(theirs), now, "gA/1")  # it did output once
    assert g.check_unmonitored(now + 0.1, live_s=2.0)[1] == [_key(theirs)]
    t = now + 0.2
    for _ in range(6):
        g.member_event("gA/1", False, now=t)
        _stream(g, theirs, t, t + 0.3, outputs=True)  # the others monitor it meanwhile
        g.check_unmonitored(t + 0.3, live_s=2.0)
        g.member_event("gA/1", True, now=t + 0.3)
        _stream(g, theirs, t + 0.3, t + 0.6, outputs=False)
        t += 0.6
    g.check_unmonitored(t, live_s=2.0)
    st = g.status()
    assert list(st["unmonitored"]) == [theirs] and st["unmonitored"][theirs]["owner"] == "gA/1"


def test_daemon_releases_and_takes_back_a_unit_afresh():
    """The daemon side: a unit another member takes over ends its period and is forgotten;
    when it comes back it starts afresh, with no false gap."""
    from test_daemon import make, sample

    from service.wire import messages as m

    d, lg, _ = make(group={"name": "g", "takeover_s": 5.0})
    g = d.member.group
    me = g.me  # ground1/0, the default station and shard
    unit = next(
        u for u in UNITS
        if owner_of(u, [me, "gB/0"]) == me and owner_of(u, [me, "gB/0", "gX/0"]) == "gX/0"
    )  # fmt: skip
    key = _key(unit)
    g.member_event("gB/0", True, "z1")
    g.join()
    g.admit(key, m.encode_meas([sample(k) for k in range(10)]), time.monotonic())
    assert d.process_pending() == 10
    g.member_event("gX/0", True, "z2")  # gX joins and takes the unit
    assert not g.owns_key(key)
    assert d.release_units() == [unit] and d.release_units() == []
    st = d.status()
    assert st["group"]["released_units"] == [unit] and key not in st["actuators"]
    assert lg.topic(f"/{unit}/service")[-1][2]["kind"] == "released"
    g.admit(key, m.encode_meas([sample(k) for k in range(10, 20)]), time.monotonic())
    assert d.process_pending() == 0  # held for gX, not ours
    # gX goes: the unit is ours again, its held message first, as a new stream
    g.member_event("gX/0", False, "z2")
    g.admit(key, m.encode_meas([sample(k) for k in range(1000, 1010)]), time.monotonic())
    assert d.process_pending() == 20
    a = d.status()["actuators"][key]
    assert a["first_seq"] == 10 and a["samples"] == 30
    # 10..19 then 1000..1009: the only gap is the one really missing from the stream
    assert a["gaps"] == 1000 - 20


def _stream(g: MonitorGroup, unit: str, t0: float, t1: float, outputs: bool) -> None:
    """Measurements of ``unit`` every 0.1 s over [t0, t1) (monotonic), with a health output
    seen after each when ``outputs``."""
    t = t0
    while t < t1:
        g.admit(_key(unit), b"x", t)
        if outputs:  # from its owner (its summary's key)
            g.output_seen(_key(unit), t, owner_of(unit, g.members))
        t += 0.1


def test_unit_owned_by_a_member_that_does_nothing_is_unmonitored():
    """A member that joins (a token) and takes units but publishes no output for them: after
    unmonitored_s every member reports those units, naming the owner; outputs end it."""
    g = MonitorGroup("g", "gA/0", lambda k, p, t: None, unmonitored_s=1.0)
    now = time.monotonic()
    g.join()
    g._joined_at = now - 10.0  # joined long ago
    g.member_event("gX/9", True)  # the silent member
    g._changed_at = now - 10.0  # ... joined long ago too
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gX/9")
    mine = next(u for u in UNITS if owner_of(u, g.members) == "gA/0")
    _stream(g, mine, now - 3.0, now, outputs=True)
    _stream(g, theirs, now - 3.0, now - 2.0, outputs=True)  # its outputs stopped 2 s ago
    _stream(g, theirs, now - 2.0, now, outputs=False)  # its meas did not
    new, back = g.check_unmonitored(now, live_s=2.0)
    assert [(k, o) for k, o, _ in new] == [(_key(theirs), "gX/9")] and back == []
    assert 1.9 < new[0][2] < 2.2
    st = g.status()
    assert list(st["unmonitored"]) == [theirs] and st["unmonitored"][theirs]["owner"] == "gX/9"
    assert g.check_unmonitored(now, live_s=2.0) == ([], [])  # raised once
    g.output_seen(_key(theirs), now + 0.1, "gX/9")  # its owner monitors it again
    assert g.check_unmonitored(now + 0.2, live_s=2.0) == ([], [_key(theirs)])
    assert g.status()["unmonitored"] == {} and g.status()["unmonitored_events"] == 1


def test_own_units_and_a_fresh_owner_are_not_judged_at_once():
    """This member's own units are judged by the others; a new owner gets unmonitored_s from
    the membership change before its units count as unmonitored."""
    g = MonitorGroup("g", "gA/0", lambda k, p, t: None, unmonitored_s=1.0)
    now = time.monotonic()
    g.join()
    g._joined_at = now - 10.0
    mine = UNITS[0]
    _stream(g, mine, now - 3.0, now, outputs=False)  # ours, its output not seen (yet)
    assert g.check_unmonitored(now, live_s=2.0) == ([], [])
    g.member_event("gB/0", True)  # a member arrives; its units have 1 s to show output
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gB/0")
    _stream(g, theirs, now - 3.0, now, outputs=False)
    assert g.check_unmonitored(now + 0.5, live_s=2.0) == ([], [])
    new, _ = g.check_unmonitored(g._changed_at + 1.2, live_s=2.0)
    assert [k for k, _, _ in new] == [_key(theirs)]


def test_unit_released_to_nobody_is_unmonitored():
    """This member released a unit (a member appeared) but no output for it follows."""
    g = MonitorGroup("g", "gA/0", lambda k, p, t: None, unmonitored_s=1.0)
    t0 = time.monotonic()
    g.join()
    unit = next(u for u in UNITS if owner_of(u, ["gA/0", "gB/0"]) == "gB/0")
    _stream(g, unit, t0, t0 + 1.0, outputs=True)  # ours, monitored
    assert g.owns_key(_key(unit))
    g.member_event("gB/0", True, now=t0 + 1.0)  # released to gB ...
    assert g.pop_released() == [_key(unit)]
    _stream(g, unit, t0 + 1.0, t0 + 3.0, outputs=False)  # ... which never outputs
    assert g.check_unmonitored(t0 + 1.5, live_s=2.0) == ([], [])  # within unmonitored_s
    new, _ = g.check_unmonitored(t0 + 3.0, live_s=2.0)
    assert [(k, o) for k, o, _ in new] == [(_key(unit), "gB/0")]


def test_no_unmonitored_while_outputs_flow_or_the_unit_is_silent():
    g = MonitorGroup("g", "gA/0", lambda k, p, t: None, unmonitored_s=1.0)
    t0 = time.monotonic()
    g.member_event("gB/0", True)
    g.join()
    units = UNITS[:20]
    for u in units:
        _stream(g, u, t0, t0 + 5.0, outputs=True)
    assert g.check_unmonitored(t0 + 5.0, live_s=2.0) == ([], [])
    # the units fell silent (no meas): nothing to monitor, nothing raised, state forgotten
    assert g.check_unmonitored(t0 + 60.0, live_s=2.0) == ([], [])
    assert g._last_meas == {} and g._last_output == {}
    # before the join nothing is judged
    h = MonitorGroup("h", "gA/0", lambda k, p, t: None, unmonitored_s=0.1)
    _stream(h, units[0], t0, t0 + 2.0, outputs=False)
    assert h.check_unmonitored(t0 + 2.0, live_s=2.0) == ([], [])


def test_fleet_page_live_view_shows_unmonitored_units():
    """``web.live.slim``: a unit a member reports unmonitored is marked, with its owner, even
    when no daemon lists it among its actuators; the daemon strip lists it too."""
    from service.edge.web.live import slim

    g = {"unmonitored": {"AC001/flap": {"owner": "ground1/9", "since": 1.0}}}
    daemons = {
        "monitor/ground1/0/status": {"station": "ground1", "shard": "0", "actuators": {},
                                     "group": g},
        "monitor/ground1/1/status": {"station": "ground1", "shard": "1", "group": g,
                                     "actuators": {"fleet/AC002/rudder/meas": {
                                         "aircraft": "AC002", "actuator": "rudder",
                                         "samples": 5}}},
    }  # fmt: skip
    view = slim(daemons, 0.0)
    assert view["units"]["AC001/flap"] == {
        "daemon": None,
        "unmonitored": True,
        "owner": "ground1/9",
    }
    assert "unmonitored" not in view["units"]["AC002/rudder"]
    assert [d["unmonitored"] for d in view["daemons"]] == [["AC001/flap"], ["AC001/flap"]]
