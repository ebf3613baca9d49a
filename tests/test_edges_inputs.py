"""The station's edges, round three (issue 50): names bounded at the intake by one grammar
that every reader accepts, a status reply judged field by field, ``status`` and ``listen``
robust against what a reply or an output carries, and a JSON ``seq`` beyond int64 a bad
sample that loses nothing else."""

from __future__ import annotations

import json

import pytest
from test_status_reply import GOOD, _Session

from service.names import MAX_NAME_CHARS, is_name, is_unit

LONG = "a" * (MAX_NAME_CHARS + 1)  # the probe's 129 characters
MAX = "b" * MAX_NAME_CHARS
UNIT_GOOD = "fleet/AC001/elevator_L/meas"


def _status_funcs():
    from service.cli.commands.status import format_status
    from service.edge.status import query_status

    return format_status, query_status


# ----------------------------------------------------------------------------- the grammar


def test_one_grammar_with_a_length_limit():
    assert MAX_NAME_CHARS == 128
    assert is_name(MAX) and not is_name(LONG)
    assert not is_name("") and not is_name("x\n") and not is_name("a b") and not is_name(5)
    assert is_unit(f"AC001/{MAX}") and not is_unit(f"AC001/{LONG}") and not is_unit("AC001")


def test_a_key_whose_name_ends_in_a_newline_is_not_a_key():
    """``^...$`` with ``re.match`` let ``x\\n`` through as a name."""
    from service.wire import messages as m

    with pytest.raises(m.MessageError):
        m.parse_meas_key("fleet/AC001/x\n/meas")
    with pytest.raises(m.MessageError):
        m.parse_meas_key(f"fleet/AC001/{LONG}/meas")
    assert m.parse_meas_key(f"fleet/AC001/{MAX}/meas") == ("AC001", MAX)


def test_the_intake_refuses_a_name_longer_than_the_grammar_and_admits_the_longest():
    from test_daemon import make, sample

    from service.wire import messages as m

    d, _, _ = make()
    long_key, max_key = f"fleet/AC001/{LONG}/meas", f"fleet/AC001/{MAX}/meas"
    assert not d.submit(long_key, m.encode_meas([sample(0)]))
    assert d.submit(max_key, m.encode_meas([sample(0)]))
    d.process_pending()
    st = d.status()
    assert st["unknown"]["invalid_key"] == 1, st["unknown"]
    assert list(st["actuators"]) == [max_key]
    # every reader accepts every name the intake admits
    from service.edge.status import check_reply

    reply = check_reply("monitor/ground1/0/status", json.dumps(st).encode())
    assert "malformed" not in reply and not reply.get("bad_units"), reply.get("bad_units")
    from service.edge.metrics import collect_status

    fams = {f.name: f for f in collect_status(st)}
    (s,) = fams["servowatch_unit_samples"].samples
    assert s.labels["actuator"] == MAX


def test_the_store_accepts_every_name_the_intake_admits_and_no_other():
    from service.store import check_actuator

    assert check_actuator(f"{MAX}/{MAX}") == f"{MAX}/{MAX}"
    with pytest.raises(ValueError, match="at most 128"):
        check_actuator(f"AC001/{LONG}")


def test_the_store_keeps_a_unit_of_the_longest_names(store_url):
    from test_store import make_period

    from service.store import open_store

    unit = f"{MAX}/{MAX}"
    s = open_store(store_url)
    try:
        assert s.add_period(make_period(unit, 1))
        assert [p.actuator for p in s.periods(unit)] == [unit]
        with pytest.raises(ValueError, match="at most 128"):
            s.add_period(make_period(f"AC001/{LONG}", 1))
    finally:
        s.close()


# ----------------------------------------------------------------------- the status reply


def _reply(**changes) -> dict:
    st = json.loads(json.dumps(GOOD))
    st.update(changes)
    return st


def test_one_bad_unit_shows_the_rest_and_is_named():
    format_status, query_status = _status_funcs()
    st = _reply()
    bad_key = f"fleet/AC001/{LONG}/meas"
    st["actuators"][bad_key] = {**st["actuators"][UNIT_GOOD], "actuator": LONG}
    st["actuators"]["fleet/AC001/rudder/meas"] = {"aircraft": "AC001", "actuator": "rudder"}
    daemons = query_status(_Session({"monitor/ground1/0/status": json.dumps(st).encode()}))
    r = daemons["monitor/ground1/0/status"]
    assert "malformed" not in r, r
    assert list(r["actuators"]) == [UNIT_GOOD]
    assert set(r["bad_units"]) == {bad_key[:80], "fleet/AC001/rudder/meas"}, r["bad_units"]
    text = format_status(daemons)
    assert "AC001/elevator_L: 10 samples" in text, text
    assert "BAD UNIT 'fleet/AC001/rudder/meas'" in text and "BAD UNIT 'fleet/AC001/aaaa" in text
    from service.edge.web.live import slim

    live = slim(daemons, 1.0)
    (d,) = live["daemons"]
    assert d["state"] == "ok" and d["units"] == 1 and len(d["bad_units"]) == 2, d
    assert live["units"]["AC001/elevator_L"]["daemon"] == "ground1/0"


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"model": 5}, "model"),
        ({"uptime_s": "long"}, "uptime_s"),
        ({"latency_ms": "fast"}, "latency_ms"),
        ({"group": {"members": [None], "unmonitored": {}}}, "group.members"),
        ({"group": {"members": "all", "unmonitored": {}}}, "group.members"),
        ({"foxglove": {"listen": 5, "sent": "many"}}, "foxglove.listen"),
        ({"silent": [None, "AC001/x"]}, "silent"),
        ({"alarms": [{"kind": 5}]}, "alarms"),
    ],
)
def test_a_single_bad_field_never_discards_the_daemon(changes, field):
    format_status, query_status = _status_funcs()
    st = _reply(**changes)
    daemons = query_status(_Session({"monitor/ground1/0/status": json.dumps(st).encode()}))
    r = daemons["monitor/ground1/0/status"]
    assert "malformed" not in r, r
    assert field in r["bad_fields"], r.get("bad_fields")
    text = format_status(daemons)  # no traceback
    assert "AC001/elevator_L: 10 samples" in text, text
    assert f"BAD FIELD {field}" in text, text


def test_members_null_prints_without_a_traceback():
    """The probe's ``members: [null]`` crashed ``servowatch status`` (exit 1)."""
    format_status, query_status = _status_funcs()
    st = _reply(group={"name": "fleet", "members": [None, "ground1/0"], "joined": True,
                       "unmonitored": {}})  # fmt: skip
    daemons = query_status(_Session({"monitor/ground1/0/status": json.dumps(st).encode()}))
    text = format_status(daemons)
    assert "AC001/elevator_L: 10 samples" in text


ESC = "\x1b[2J\x1b[H"  # clear the screen, cursor home


def test_control_characters_in_every_string_shown_are_escaped():
    format_status, query_status = _status_funcs()
    st = _reply(
        model=f"WH{ESC}all units OK",
        log_failure=f"disk\rall units OK{ESC}",
        feed_failure="x\x1b]0;title\x07",
        group={"name": f"fleet{ESC}", "members": [f"ground1/0{ESC}"], "joined": True,
               "unmonitored": {f"AC001/x{ESC}": {"owner": f"o{ESC}"}}},
        foxglove={"listen": f"127.0.0.1:1{ESC}", "guard": {"listener": f"ok{ESC}"}},
    )  # fmt: skip
    a = st["actuators"][UNIT_GOOD]
    a["alarms"] = [{"kind": f"leak{ESC}\u2028forged", "value": 2.0}]
    a["rul"] = {"median_h": 3.0, "status": f"x{ESC}"}
    daemons = query_status(_Session({"monitor/ground1/0/status": json.dumps(st).encode()}))
    text = format_status(daemons)
    for ch in ("\x1b", "\r", "\x07", "\u2028"):
        assert ch not in text, repr(text)
    assert "\\x1b[2J" in text  # shown, escaped
    assert all(ln.startswith(("monitor/", " ")) for ln in text.splitlines()), text


# ------------------------------------------------------------------------------- listen


def test_listen_bounds_the_keys_it_remembers():
    from service.cli.commands.listen import OutputListener
    from service.wire import messages as m

    lis = OutputListener(echo=False, max_keys=10)
    payload = m.encode_json({"t": 1.0, "leak_ratio": 1.0})
    for k in range(300):
        lis.on_sample(f"fleet/AC001/a{k}/health", payload, "application/json")
    sm = lis.summary()
    assert sm["received"] == 300 and len(sm["outputs"]) == 10 and sm["evicted"] == 290
    assert "fleet/AC001/a299/health" in sm["outputs"]  # the most recent kept
    lis.on_sample("fleet/AC001/a295/health", payload, "application/json")  # touched: kept
    for k in range(300, 309):
        lis.on_sample(f"fleet/AC001/a{k}/health", payload, "application/json")
    assert "fleet/AC001/a295/health" in lis.summary()["outputs"]


def test_listen_escapes_nothing_it_did_not_parse():
    """A key with a trailing newline is a malformed output, not a printed line."""
    import io

    from service.cli.commands.listen import OutputListener
    from service.wire import messages as m

    out = io.StringIO()
    lis = OutputListener(echo=True, out=out)
    lis.on_sample("fleet/AC001/x\n/health", m.encode_json({"t": 1.0}), "application/json")
    assert lis.malformed == 1 and out.getvalue() == ""


# ------------------------------------------------------------------- seq beyond int64


@pytest.mark.parametrize("seq", [2**63, -(2**63) - 1, 10**30])
def test_a_json_seq_beyond_int64_is_a_bad_sample_and_loses_nothing_else(seq):
    from test_daemon import KEY, KEY2, make, sample

    from service.wire import messages as m

    with pytest.raises(m.MessageError, match="seq"):
        m.decode_meas_arrays(json.dumps({"seq": seq, "t": 1.0}).encode())
    d, _, _ = make()
    good = [m.encode_json(sample(k)) for k in range(3)]
    d.submit(KEY2, good[0])
    d.submit(KEY, json.dumps({**sample(0), "seq": seq}).encode())
    d.submit(KEY2, good[1])
    d.submit(KEY, good[2])
    d.process_pending()
    st = d.status()
    assert st["errors"] == 0, st
    acts = st["actuators"]
    assert acts[KEY2]["samples"] == 2 and acts[KEY]["samples"] == 1, acts
    assert acts[KEY]["bad_total"] == 1 and acts[KEY]["bad"] == {"schema": 1}, acts[KEY]
