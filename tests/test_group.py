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
    g = MonitorGroup("g", "gA/0", lambda k, p, t: got.append(p), takeover_s=1.0)
    g.member_event("gB/0", True)
    g.join()
    theirs = next(u for u in UNITS if owner_of(u, g.members) == "gB/0")
    now = time.monotonic()
    for i, age in enumerate((5.0, 3.0, 0.5, 0.1)):
        g.admit(_key(theirs), bytes([i]), now - age)
    g.member_event("gB/0", False)
    assert got == [bytes([2]), bytes([3])]


def test_token_names():
    g = MonitorGroup("fleetA", "gA/0", lambda *a: None)
    tok = group_token("gB", "1", "fleetA")
    assert tok == "monitor/gB/1/group/fleetA"
    assert g.member_name_of_token(tok) == "gB/1"
    assert g.member_name_of_token("monitor/gB/1/group/other") is None
    assert g.member_name_of_token("monitor/gB/1/alive") is None
