"""``servowatch status`` and the fleet page survive any status reply (issue 43, item 4):
malformed replies are counted and shown as such, and a reply that claims another daemon's
name is told apart by its key (which the router ties to the replier's certificate)."""

from __future__ import annotations

import json
from dataclasses import dataclass

from service.cli.commands.status import format_status
from service.edge.status import query_status
from service.edge.web.live import slim

GOOD = {
    "station": "ground1", "shard": "0", "state": "ok", "model": "WH", "pid": 7, "uptime_s": 3.0,
    "samples": 10, "dropped": 0, "bad": 0, "missed": 0, "latency_ms": {"p50": 1.0, "p99": 2.0},
    "silent": [], "log_failure": None,
    "actuators": {"fleet/AC001/elevator_L/meas": {
        "aircraft": "AC001", "actuator": "elevator_L", "samples": 10, "dropped": 0, "gaps": 0,
        "bad": {"clock": 1}, "missed": 0, "silent": False, "est": {"c_lk": 1e-12},
        "alarms": []}},
    "group": {"name": "fleet", "members": ["ground1/0"], "joined": True, "unmonitored": {}},
}  # fmt: skip

#: replies an identity with a monitor certificate can send on its own key: unreadable
MALFORMED = [
    b"[]",
    b'"text"',
    b"{",
    b"\xff\xfe",
    b"[" * 100_000 + b"]" * 100_000,  # deeper than the parser goes
    json.dumps({k: v for k, v in GOOD.items() if k != "station"}).encode(),
    json.dumps({**GOOD, "shard": "x" * 129}).encode(),
]

#: ... and with a bad field or unit: the rest is shown, the bad ones named (issue 50)
PARTIAL = [
    json.dumps({**GOOD, "actuators": {"x": "y"}}).encode(),
    json.dumps({**GOOD, "actuators": {"x": {"aircraft": "AC001", "actuator": "a"}}}).encode(),
    json.dumps({**GOOD, "latency_ms": "fast"}).encode(),
    json.dumps({**GOOD, "group": {"members": "all", "unmonitored": {}}}).encode(),
    json.dumps({**GOOD, "group": {"members": [], "unmonitored": {"AC001/x": 5}}}).encode(),
    json.dumps({**GOOD, "foxglove": {"listen": 5, "sent": "many"}}).encode(),
    json.dumps({**GOOD, "foxglove": {"listen": "x", "guard": {"buffered_bytes": "lots"}}}).encode(),
    json.dumps({**GOOD, "uptime_s": "long"}).encode(),
    json.dumps(
        {
            **GOOD,
            "actuators": {
                "k": {**GOOD["actuators"]["fleet/AC001/elevator_L/meas"], "est": {"c_lk": "leaky"}}
            },
        }
    ).encode(),  # fmt: skip
]


@dataclass
class _Payload:
    data: bytes

    def to_bytes(self) -> bytes:
        return self.data


@dataclass
class _Ok:
    key_expr: str
    payload: _Payload


@dataclass
class _Reply:
    ok: _Ok | None


class _Session:
    def __init__(self, replies: dict[str, bytes]) -> None:
        self.replies = replies

    def get(self, selector, timeout=2.0):
        return [_Reply(_Ok(k, _Payload(v))) for k, v in self.replies.items()]


def test_malformed_replies_are_counted_and_shown_as_such():
    for payload in MALFORMED:
        replies = {"monitor/ground1/0/status": json.dumps(GOOD).encode(),
                   "monitor/ground1/1/status": payload}  # fmt: skip
        daemons = query_status(_Session(replies))
        bad = daemons["monitor/ground1/1/status"]
        assert "malformed" in bad, (payload[:80], bad)
        text = format_status(daemons)
        assert "monitor/ground1/1/status': MALFORMED reply" in text, text
        assert "AC001/elevator_L: 10 samples" in text  # the good daemon still shown
        live = slim(daemons, 1.0)
        states = {d["key"]: d["state"] for d in live["daemons"]}
        assert states == {"monitor/ground1/0/status": "ok", "monitor/ground1/1/status": "malformed"}
        assert live["units"]["AC001/elevator_L"]["daemon"] == "ground1/0"


def test_a_bad_field_or_unit_is_named_and_the_rest_shown():
    for payload in PARTIAL:
        own = json.dumps({**json.loads(payload), "shard": "1"}).encode()  # its key's name
        replies = {"monitor/ground1/0/status": json.dumps(GOOD).encode(),
                   "monitor/ground1/1/status": own}  # fmt: skip
        daemons = query_status(_Session(replies))
        r = daemons["monitor/ground1/1/status"]
        assert "malformed" not in r and (r.get("bad_fields") or r.get("bad_units")), r
        text = format_status(daemons)
        assert "BAD FIELD" in text or "BAD UNIT" in text, text
        assert "AC001/elevator_L: 10 samples" in text
        live = slim(daemons, 1.0)
        states = {d["key"]: d["state"] for d in live["daemons"]}
        assert states == {"monitor/ground1/0/status": "ok", "monitor/ground1/1/status": "ok"}


def test_a_reply_claiming_another_daemons_name_is_told_apart():
    rogue = {
        **GOOD,  # "ground1/0", on ground1/1's key: it lists the unit and marks it unmonitored
        "actuators": {"fleet/AC001/elevator_L/meas": {
            **GOOD["actuators"]["fleet/AC001/elevator_L/meas"], "samples": 999}},
        "group": {**GOOD["group"], "unmonitored": {"AC001/elevator_L": {"owner": "ground1/0"}}},
    }  # fmt: skip
    replies = {"monitor/ground1/0/status": json.dumps(GOOD).encode(),
               "monitor/ground1/1/status": json.dumps(rogue).encode()}  # fmt: skip
    daemons = query_status(_Session(replies))
    assert daemons["monitor/ground1/1/status"]["name_mismatch"] == "ground1/0"
    text = format_status(daemons)
    assert "monitor/ground1/1/status: NAME MISMATCH: the reply claims 'ground1/0'" in text
    assert "UNMONITORED" not in text and "999 samples" not in text
    live = slim(daemons, 1.0)
    unit = live["units"]["AC001/elevator_L"]
    assert unit["daemon"] == "ground1/0" and unit["samples"] == 10 and "unmonitored" not in unit
    (d,) = [d for d in live["daemons"] if d["key"] == "monitor/ground1/1/status"]
    assert d == {"key": "monitor/ground1/1/status", "name": "ground1/1",
                 "state": "name_mismatch", "claims": "ground1/0"}  # fmt: skip


def test_a_real_daemons_status_is_well_formed():
    from test_daemon import KEY, make, sample

    from service.edge.status import check_reply
    from service.wire import messages as m

    d, _, _ = make()
    d.submit(KEY, m.encode_meas([sample(k) for k in range(5)]))
    d.process_pending()
    st = json.loads(json.dumps(d.status()))
    assert check_reply("monitor/ground1/0/status", json.dumps(st).encode()) == st
