"""The secure station probed from outside (issue 33, items 1 and 2), on the shipped configs
and the script's PKI, every party in its own process on loopback.

- a monitor certificate cannot claim other shards' group tokens (each daemon has its own
  identity, ``monitor.<station>.<shard>``, and the rules let it hold only its own): the
  daemon keeps its units and its output;
- a legitimate member that joins and takes units without processing them makes them
  ``unmonitored`` (status, ``servowatch status``, the fleet page's live view) until it leaves;
- a ``sim-AC001`` certificate cannot make a real actuator virtual: which actuators are virtual
  is the router's configuration, and ``servowatch inject`` refuses the rest with exit 1.
"""

from __future__ import annotations

import json
import shutil
import signal
import time

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl is needed for the PKI"),
]

from test_security import AC, ACT, Station, _web_live, live_url  # noqa: E402

UNIT = f"{AC}/{ACT}"
KEY = f"fleet/{UNIT}/meas"


def _daemon_status(st: Station, tag: str) -> dict:
    res = st.status("operator", tag)
    assert res["rc"] == 0, res
    return res["json"]["daemons"]["monitor/ground1/0/status"]


def _wait_ready(st: Station, p, tag: str) -> None:
    deadline = time.monotonic() + 60
    while '"ready"' not in (st.tmp / f"{tag}.out").read_text():
        assert p.poll() is None, (st.tmp / f"{tag}.err").read_text()[-2000:]
        assert time.monotonic() < deadline, f"{tag} not ready"
        time.sleep(0.1)


def _stop(p) -> None:
    p.send_signal(signal.SIGTERM)
    p.wait(30)


def _until(fn, pred, timeout: float = 30.0):
    """``fn()`` once ``pred`` holds on it, or its last value after ``timeout`` [s]."""
    deadline = time.monotonic() + timeout
    while True:
        v = fn()
        if pred(v) or time.monotonic() > deadline:
            return v
        time.sleep(0.5)


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("probe")
    st = Station(tmp)
    r: dict = {"station": st}
    try:
        daemon, act, web = st.monitored()
        r["before"] = _until(  # the unit monitored (a loaded machine starts slowly)
            lambda: _daemon_status(st, "s_before"),
            lambda s: s["actuators"].get(KEY, {}).get("outputs"),
            60.0,
        )

        # 1. other shards' group tokens, with the daemon's own certificate and another's
        rogues = [
            st.popen(["token", *[f"monitor/ground1/{n}/group/fleet/{{zid}}" for n in (8, 9, 10)]],
                     f"rogue_{cn}", st.env(cn), True)
            for cn in ("monitor.ground1.0", "monitor.ground1.1")
        ]  # fmt: skip
        for p, cn in zip(rogues, ("monitor.ground1.0", "monitor.ground1.1"), strict=True):
            _wait_ready(st, p, f"rogue_{cn}")
        time.sleep(3.0)
        r["rogue"] = _daemon_status(st, "s_rogue")
        for p in rogues:
            _stop(p)

        # 2. a legitimate member (its own token) that processes nothing: unmonitored
        idle = st.popen(["token", "monitor/ground1/1/group/fleet/{zid}"], "idle",
                        st.env("monitor.ground1.1"), True)  # fmt: skip
        _wait_ready(st, idle, "idle")
        r["idle"] = _until(lambda: _daemon_status(st, "s_idle"),
                           lambda s: UNIT in s["group"]["unmonitored"])  # fmt: skip
        r["idle_text"] = st.run(["status", "--timeout", "2", *st.flags("operator")], "s_text")
        r["idle_live"] = _web_live_until(tmp / "web.err", web)
        _stop(idle)
        # the idle member left: the daemon takes the unit back, outputs resume
        r["back"] = _until(lambda: _daemon_status(st, "s_back"),
                           lambda s: not s["group"]["unmonitored"])  # fmt: skip

        # 3. a virtual actuator's certificate claiming a real actuator
        fake = f"fleet/{AC}/flap_real"
        fv = st.popen(["token", f"{fake}/@virtual"], "fake_token", st.env("sim-AC001"), True)
        fq = st.popen(["serve", f"{fake}/@fault"], "fake_fault", st.env("sim-AC001"), True)
        _wait_ready(st, fv, "fake_token")
        _wait_ready(st, fq, "fake_fault")
        time.sleep(1.0)
        r["inject"] = st.run(
            ["inject", "--aircraft", AC, "--actuator", "flap_real", "--fault", "leak", "--value",
             "6e-13", "--timeout", "3", "--json", *st.flags("operator")], "inject_fake",
        )  # fmt: skip
        _stop(fv)
        _stop(fq)
        r["fake_fault"] = json.loads((tmp / "fake_fault.out").read_text().strip().splitlines()[-1])
        r["inject_real"] = st.run(
            ["inject", "--aircraft", AC, "--actuator", ACT, "--fault", "clear", "--json",
             *st.flags("operator")], "inject_real",
        )  # fmt: skip
        _stop(web)
        _stop(act)
        _stop(daemon)
        from service.log import read_log

        (mcap,) = tmp.glob("servowatch-ground1-0-*.mcap")
        r["events"] = [row[2] for row in read_log(mcap, [f"/fleet/{UNIT}/service"])]
        yield r
    finally:
        st.close()


def _web_live_until(out, web, timeout: float = 20.0) -> dict:
    """The page's /api/live once it shows the unit unmonitored (or the last answer)."""
    import urllib.request

    live = _web_live(out, web)
    url = live_url(out)
    deadline = time.monotonic() + timeout
    while not live.get("units", {}).get(UNIT, {}).get("unmonitored"):
        if time.monotonic() > deadline:
            break
        time.sleep(0.5)
        with urllib.request.urlopen(url, timeout=5) as resp:
            live = json.loads(resp.read())
    return live


def test_a_monitor_certificate_cannot_claim_other_shards(probe):
    before, rogue = probe["before"], probe["rogue"]
    assert rogue["group"]["members"] == ["ground1/0"], rogue["group"]
    assert rogue["group"]["released"] == 0 and rogue["group"]["released_units"] == []
    a0, a1 = before["actuators"][KEY], rogue["actuators"][KEY]
    assert a1["outputs"] - a0["outputs"] > 100, (a0["outputs"], a1["outputs"])  # still working
    assert rogue["group"]["unmonitored"] == {}
    log = probe["station"].router_log()
    for cn in ("monitor.ground1.0", "monitor.ground1.1"):
        assert any(
            f"CertCommonName({cn})" in ln
            and "unauthorized to Declare/Undeclare Liveliness Token" in ln
            and "monitor/ground1/8/group/fleet/" in ln
            for ln in log.splitlines()
        ), cn


def test_a_member_that_takes_units_and_does_nothing_makes_them_unmonitored(probe):
    g = probe["idle"]["group"]
    assert g["members"] == ["ground1/0", "ground1/1"], g
    assert g["unmonitored"][UNIT]["owner"] == "ground1/1", g
    assert g["released_units"] == [UNIT], g  # the idle member took it
    text = probe["idle_text"]
    assert text["rc"] == 0 and f"UNMONITORED {UNIT}" in text["out"], text
    unit = probe["idle_live"]["units"][UNIT]
    assert unit["unmonitored"] is True and unit["owner"] == "ground1/1", unit
    # the idle member left: the unit is the daemon's again and monitored
    back = probe["back"]
    assert back["group"]["unmonitored"] == {} and back["group"]["members"] == ["ground1/0"]
    # the daemon's log: never unmonitored while it owned the unit; unmonitored (owner
    # ground1/1) after the release; monitored again once it had the unit back
    events = [(e["kind"], e["value"]) for e in probe["events"]]
    kinds = [k for k, _ in events]
    k = kinds.index("released")
    assert "unmonitored" not in kinds[:k], events
    j = kinds.index("unmonitored", k)
    v = events[j][1]  # JSON text in the logs of JSON events, the object in protobuf events
    assert (json.loads(v) if isinstance(v, str) else v)["owner"] == "ground1/1", events
    assert "monitored" in kinds[j:], events


def test_a_virtual_actuator_certificate_cannot_claim_a_real_actuator(probe):
    res = probe["inject"]
    assert res["rc"] == 1, res
    assert res["json"]["ok"] is False and "not a virtual actuator" in res["json"]["message"]
    assert probe["fake_fault"]["queries"] == {}
    log = probe["station"].router_log()
    assert "CertCommonName(sim-AC001)" in log and any(
        "CertCommonName(sim-AC001)" in ln
        and "unauthorized to Declare/Undeclare Liveliness Token"
        " (ingress) on fleet/AC001/flap_real/@virtual"
        in ln
        for ln in log.splitlines()
    )
    # the listed virtual actuator still takes commands
    assert probe["inject_real"]["rc"] == 0 and probe["inject_real"]["json"]["ok"] is True
