"""One put must not blind the operator (issue 50, item 1), on the shipped secure configs and
the script's PKI, every party in its own process on loopback:

- an acquisition certificate's put on a key whose actuator name has 129 characters is refused
  at the intake (``invalid_key``), so the daemon's status still shows its units to
  ``servowatch status`` and the fleet page;
- a reply (on a monitor identity's own key) with one unit entry the readers cannot use shows
  its other units and names the bad one; the daemon is not discarded.
"""

from __future__ import annotations

import json
import shutil
import time

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed for the PKI"),
]

from test_secure_insider_e2e import _live  # noqa: E402
from test_secure_probe_e2e import _stop, _until, _wait_ready  # noqa: E402
from test_security import AC, ACT, Station, _web_live, live_url  # noqa: E402

UNIT = f"{AC}/{ACT}"
LONG = "a" * 129
LONG_KEY = f"fleet/{AC}/{LONG}/meas"
OWN = "monitor/ground1/0/status"
ROGUE = "monitor/ground1/1/status"


@pytest.fixture(scope="module")
def blinding(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("blinding")
    st = Station(tmp)
    r: dict = {"station": st}
    try:
        daemon, act, web = st.monitored()
        _web_live(tmp / "web.err", web)
        url = live_url(tmp / "web.err")
        _until(lambda: st.status("operator", "s0")["json"],
               lambda j: j and UNIT in str(j["daemons"].get(OWN, {}).get("actuators")))  # fmt: skip

        # 1. the aircraft's own acquisition identity puts on a 129-character actuator name
        put = st.popen(["put", LONG_KEY, "x", "50"], "long_put", st.env(f"acq-{AC}"), True)
        put.wait(60)
        time.sleep(1.0)
        r["text"] = st.run(["status", "--timeout", "2", *st.flags("operator")], "s_long_text")
        r["json"] = st.status("operator", "s_long_json")
        r["live"] = _until(lambda: _live(url), lambda lv: lv["queried_s"] and lv["daemons"])

        # 2. a reply with one good and one bad unit, on a monitor identity's own key
        good = {"aircraft": AC, "actuator": "rudder", "samples": 5, "dropped": 0, "gaps": 0,
                "bad": 0}  # fmt: skip
        rogue = {
            "station": "ground1", "shard": "1", "state": "ok", "samples": 5,
            "actuators": {f"fleet/{AC}/rudder/meas": good,
                          LONG_KEY: {**good, "actuator": LONG}},
        }  # fmt: skip
        a = st.popen(["answer", ROGUE, json.dumps(rogue)], "answer_unit",
                     st.env("monitor.ground1.1"), True)  # fmt: skip
        _wait_ready(st, a, "answer_unit")
        r["unit_text"] = st.run(["status", "--timeout", "2", *st.flags("operator")], "s_unit")
        r["unit_json"] = st.status("operator", "s_unit_json")
        r["unit_live"] = _until(lambda: _live(url),
                                lambda lv: ROGUE in {d["key"] for d in lv["daemons"]})  # fmt: skip
        _stop(a)
        _stop(web)
        _stop(act)
        _stop(daemon)
        yield r
    finally:
        st.close()


def test_a_129_character_name_is_refused_at_the_intake_and_blinds_nobody(blinding):
    js = blinding["json"]
    assert js["rc"] == 0 and js["json"]["malformed"] == 0, js
    own = js["json"]["daemons"][OWN]
    assert "malformed" not in own, own.get("malformed")
    assert own["unknown"].get("invalid_key", 0) >= 1, own["unknown"]
    assert not [k for k in own["actuators"] if LONG in k]
    assert f"fleet/{UNIT}/meas" in own["actuators"]
    text = blinding["text"]["out"]
    assert f"{UNIT}:" in text and "MALFORMED" not in text, text
    (d,) = [d for d in blinding["live"]["daemons"] if d["key"] == OWN]
    assert d["state"] == "ok", d
    assert blinding["live"]["units"][UNIT]["daemon"] == "ground1/0"


def test_a_reply_with_one_bad_unit_shows_the_rest_and_names_it(blinding):
    rogue = blinding["unit_json"]["json"]["daemons"][ROGUE]
    assert "malformed" not in rogue, rogue
    assert list(rogue["actuators"]) == [f"fleet/{AC}/rudder/meas"]
    assert [k for k in rogue["bad_units"] if k.startswith(f"fleet/{AC}/aaaa")], rogue
    text = blinding["unit_text"]["out"]
    assert f"{AC}/rudder: 5 samples" in text and f"{UNIT}:" in text, text
    assert f"BAD UNIT 'fleet/{AC}/aaaa" in text, text
    live = blinding["unit_live"]
    states = {d["key"]: d["state"] for d in live["daemons"]}
    assert states == {OWN: "ok", ROGUE: "ok"}, states
    assert live["units"][f"{AC}/rudder"]["daemon"] == "ground1/1"
