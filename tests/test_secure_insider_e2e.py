"""The secure station against an insider (issue 43, items 2, 4 and 5), on the shipped configs
and the script's PKI, every party in its own process on loopback:

- a valid monitor certificate of another station (``monitor.ground2.0``) holding its own
  group token does not join station ground1's group;
- health (and outputs summaries) that do not come from a unit's owner cannot mask
  ``unmonitored``: an idle member's unit stays unmonitored while others put its health;
- a malformed status reply, and one that claims another daemon's name, on a monitor
  identity's own key: ``servowatch status`` and the fleet page survive and tell them apart;
- a ``router`` certificate cannot put meas of an aircraft the linked stations do not serve;
- a meas key with a newline is refused at the intake and forges no ``--plain-logs`` line.
"""

from __future__ import annotations

import json
import shutil
import time
import urllib.request

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed for the PKI"),
]

from test_secure_probe_e2e import _daemon_status, _stop, _until, _wait_ready  # noqa: E402
from test_security import AC, ACT, Station, _web_live, live_url  # noqa: E402

UNIT = f"{AC}/{ACT}"
KEY = f"fleet/{UNIT}/meas"
FORGED = "2026-12-03 12:00:00,000 ERROR servowatch.daemon FORGED LINE"


def _live(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=5) as resp:
        return json.loads(resp.read())


@pytest.fixture(scope="module")
def insider(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("insider")
    st = Station(tmp)
    r: dict = {"station": st}
    try:
        daemon, act, web = st.monitored()
        _web_live(tmp / "web.err", web)
        url = live_url(tmp / "web.err")
        time.sleep(2.0)

        # 1. station B's daemon certificate, its own token in ground1's group
        b = st.popen(["token", "monitor/ground2/0/group/fleet/{zid}"], "b_token",
                     st.env("monitor.ground2.0"), True)  # fmt: skip
        _wait_ready(st, b, "b_token")
        time.sleep(3.0)
        r["b"] = _daemon_status(st, "s_b")
        _stop(b)

        # 2. an idle member takes the unit; other identities put its health and claim it
        idle = st.popen(["token", "monitor/ground1/1/group/fleet/{zid}"], "idle",
                        st.env("monitor.ground1.1"), True)  # fmt: skip
        maskers = [
            st.popen(["put", f"fleet/{UNIT}/health", '{"t": 1.0}', "1500"], f"mask_{cn}",
                     st.env(cn), True)
            for cn in ("monitor.ground2.0", "monitor.ground1.0")
        ] + [
            st.popen(["put", "monitor/ground2/0/outputs", json.dumps({"units": [UNIT]}), "1500"],
                     "mask_summary", st.env("monitor.ground2.0"), True)
        ]  # fmt: skip
        _wait_ready(st, idle, "idle")
        r["idle"] = _until(lambda: _daemon_status(st, "s_idle"),
                           lambda s: UNIT in s["group"]["unmonitored"])  # fmt: skip
        time.sleep(2.0)  # and it stays so while the maskers put
        r["idle_later"] = _daemon_status(st, "s_idle2")
        _stop(idle)
        for p in maskers:
            p.kill()
            p.wait(10)
        r["back"] = _until(lambda: _daemon_status(st, "s_back"),
                           lambda s: not s["group"]["unmonitored"])  # fmt: skip

        # 3. status replies on a monitor identity's own key: malformed, then a false name
        rogue_status = {
            "station": "ground1", "shard": "0", "state": "ok", "samples": 1,
            "actuators": {KEY: {"aircraft": AC, "actuator": ACT, "samples": 1, "dropped": 0,
                                "gaps": 0, "bad": 0}},
            "group": {"members": ["ground1/0"], "unmonitored": {UNIT: {"owner": "ground1/0"}}},
        }  # fmt: skip
        for tag, text in (("malformed", '[{"actuators": 1}]'), ("claim", json.dumps(rogue_status))):
            a = st.popen(["answer", "monitor/ground1/1/status", text], f"answer_{tag}",
                         st.env("monitor.ground1.1"), True)  # fmt: skip
            _wait_ready(st, a, f"answer_{tag}")
            r[f"{tag}_text"] = st.run(["status", "--timeout", "2", *st.flags("operator")],
                                      f"s_{tag}_text")  # fmt: skip
            r[f"{tag}_json"] = st.status("operator", f"s_{tag}_json")
            r[f"{tag}_live"] = _until(
                lambda: _live(url),
                lambda lv: "monitor/ground1/1/status" in {d["key"] for d in lv["daemons"]},
            )
            _stop(a)

        # 4. the router certificate originating meas of an aircraft nobody serves; 5. a key
        # with a newline from the aircraft's own acquisition identity
        rt = st.popen(["put", "fleet/AC999/ghost/meas", "x", "50"], "router_put",
                      st.env("router"), True)  # fmt: skip
        nl = st.popen(["put", f"fleet/{AC}/x\n{FORGED}/meas", "x", "50"], "newline_put",
                      st.env(f"acq-{AC}"), True)  # fmt: skip
        rt.wait(60)
        nl.wait(60)
        time.sleep(1.0)
        r["after_puts"] = _daemon_status(st, "s_puts")
        _stop(web)
        _stop(act)
        _stop(daemon)
        r["daemon_err"] = (tmp / "daemon.err").read_text()
        yield r
    finally:
        st.close()


def test_a_daemon_of_another_station_cannot_join_the_group(insider):
    g = insider["b"]["group"]
    assert g["members"] == ["ground1/0"] and g["released_units"] == [], g
    assert g["foreign_tokens"] >= 1 and g["unmonitored"] == {}, g


def test_health_not_from_the_units_owner_cannot_mask_unmonitored(insider):
    for s in (insider["idle"], insider["idle_later"]):
        g = s["group"]
        assert g["members"] == ["ground1/0", "ground1/1"], g
        assert g["unmonitored"][UNIT]["owner"] == "ground1/1", g
    assert insider["idle_later"]["group"]["unmonitored_events"] == 1
    back = insider["back"]["group"]
    assert back["unmonitored"] == {} and back["members"] == ["ground1/0"], back


def test_status_and_the_page_survive_a_malformed_reply(insider):
    text = insider["malformed_text"]
    assert text["rc"] == 0, text
    assert "'monitor/ground1/1/status': MALFORMED reply" in text["out"], text["out"]
    assert f"{UNIT}:" in text["out"]  # the real daemon still listed
    js = insider["malformed_json"]["json"]
    assert js["malformed"] == 1 and "malformed" in js["daemons"]["monitor/ground1/1/status"]
    live = insider["malformed_live"]
    states = {d["key"]: d["state"] for d in live["daemons"]}
    assert states == {"monitor/ground1/0/status": "ok", "monitor/ground1/1/status": "malformed"}
    assert live["units"][UNIT]["daemon"] == "ground1/0"


def test_a_reply_claiming_another_daemons_name_is_told_apart(insider):
    text = insider["claim_text"]
    assert text["rc"] == 0, text
    assert "monitor/ground1/1/status: NAME MISMATCH: the reply claims 'ground1/0'" in text["out"]
    assert "UNMONITORED" not in text["out"]
    live = insider["claim_live"]
    unit = live["units"][UNIT]
    assert unit["daemon"] == "ground1/0" and not unit.get("unmonitored"), unit
    (d,) = [d for d in live["daemons"] if d["key"] == "monitor/ground1/1/status"]
    assert d["state"] == "name_mismatch" and d["name"] == "ground1/1" and d["claims"] == "ground1/0"


def test_a_router_certificate_cannot_put_meas_of_an_unserved_aircraft(insider):
    s = insider["after_puts"]
    assert not [k for k in s["actuators"] if "AC999" in k], list(s["actuators"])
    log = insider["station"].router_log()
    assert any("CertCommonName(router)" in ln and "fleet/AC999/ghost/meas" in ln
               and "unauthorized" in ln for ln in log.splitlines())  # fmt: skip


def test_a_key_with_a_newline_is_refused_and_forges_no_log_line(insider):
    s = insider["after_puts"]
    assert s["unknown"].get("invalid_key", 0) >= 1, s["unknown"]
    assert not [k for k in s["actuators"] if "FORGED" in k]
    lines = insider["daemon_err"].splitlines()
    assert not [ln for ln in lines if ln.startswith(FORGED[:10]) and "FORGED LINE" in ln
                and "invalid_key" not in ln], [ln for ln in lines if "FORGED" in ln]  # fmt: skip
    assert any("invalid_key" in ln and "FORGED LINE" in ln for ln in lines)
