"""Two daemons of one monitor group share four virtual actuators through a router, every
piece in its own process on loopback; one daemon is killed (-9) and the other takes its units
over without losing a sample: it starts each from the messages it held, at or before the
last sample the dead one had accepted, and then has no gap."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from service.daemon.group import owner_of
from tests.test_service_e2e import Net

pytestmark = pytest.mark.slow

zenoh = pytest.importorskip("zenoh")

A, B = "gA/0", "gB/0"
RATE = 200  # Hz per actuator: four of them and two daemons on a 2-core machine


def _units() -> list[str]:
    """Four unit names, two owned by each member (rendezvous is deterministic)."""
    mine = {A: [], B: []}
    for k in range(100):
        u = f"AC001/act{k}"
        o = owner_of(u, [A, B])
        if len(mine[o]) < 2:
            mine[o].append(u)
        if all(len(v) == 2 for v in mine.values()):
            return mine[A] + mine[B]
    raise AssertionError("no split found")


def _statuses(net: Net) -> dict[str, dict]:
    out = {}
    for reply in net.session.get("monitor/*/*/status", timeout=1.0):
        if reply.ok is not None:
            st = json.loads(reply.ok.payload.to_bytes())
            out[f"{st['station']}/{st['shard']}"] = st
    return out


def _owned(st: dict) -> dict[str, dict]:
    return {f"{a['aircraft']}/{a['actuator']}": a for a in st["actuators"].values()}


def _wait(net: Net, pred, what: str, timeout: float = 60.0) -> dict[str, dict]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        sts = _statuses(net)
        if pred(sts):
            return sts
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}; last {_statuses(net)}")


def test_group_shares_units_and_takes_over_without_loss(net: Net, tmp_path):
    units = _units()
    daemons = {}
    for name in (A, B):
        station = name.split("/")[0]
        cfg = tmp_path / f"{station}.toml"
        cfg.write_text(
            f'station = "{station}"\nshard = "0"\nstore = "off"\n[group]\nname = "fleet"\ntakeover_s = 5.0\n'
            'stations = ["gA", "gB"]\n'
        )
        daemons[name] = net.start("run", "--config", str(cfg), "--log", str(tmp_path / f"{station}.mcap"),
                                  "--no-rotate", "--json", start_new_session=True)  # fmt: skip
    _wait(net, lambda s: set(s) == {A, B}, "both daemons' status")
    for u in units:
        ac, act = u.split("/")
        net.start("actuator", "--scenario", "healthy_noise", "--aircraft", ac, "--actuator", act,
                  "--rate", str(RATE), "--duration", "120")  # fmt: skip

    def shared(s: dict) -> bool:
        if set(s) != {A, B}:
            return False
        own = {n: _owned(st) for n, st in s.items()}
        return all(u in own[owner_of(u, [A, B])] and own[owner_of(u, [A, B])][u]["samples"] > RATE
                   for u in units)  # fmt: skip

    sts = _wait(net, shared, "every unit monitored by its owner", timeout=90)
    own = {n: _owned(st) for n, st in sts.items()}
    assert set(own[A]) == set(units[:2]) and set(own[B]) == set(units[2:])  # disjoint, complete
    for n in (A, B):
        g = sts[n]["group"]
        assert g["members"] == [A, B] and g["joined"] and g["held_units"] == 2
        assert g["unmonitored"] == {} and g["unmonitored_events"] == 0  # both members work
    # kill A with its log process; its last accepted sample of each unit, just before
    last_a = {u: own[A][u]["last_seq"] for u in units[:2]}
    os.killpg(daemons[A].pid, signal.SIGKILL)
    daemons[A].wait(10)
    t_kill = time.monotonic()

    def taken_over(s: dict) -> bool:
        o = _owned(s[B]) if B in s else {}
        return all(u in o and o[u]["samples"] > RATE for u in units)

    sts = _wait(net, taken_over, "B monitoring every unit", timeout=30)
    took_s = time.monotonic() - t_kill
    b = sts[B]
    assert b["group"]["members"] == [B] and b["group"]["takeovers"] == 2
    for u in units[:2]:
        a = _owned(b)[u]
        # B started the unit from its held messages, at or before what A had accepted when
        # it was last asked, and has had no gap since: nothing fell between the two
        assert a["first_seq"] <= last_a[u], (u, a["first_seq"], last_a[u])
        assert a["gaps"] == 0 and a["missed"] == 0, a
    assert took_s < 15, took_s
    # a takeover well within unmonitored_s (5 s) raises no 'unmonitored'
    assert b["group"]["unmonitored"] == {} and b["group"]["unmonitored_events"] == 0, b["group"]
